"""Mapping files: which field of a recording feeds which column of a drive.

``graphpos import rosbag`` (:mod:`graphpos.io.rosbag`) and ``graphpos import
csv`` (:mod:`graphpos.io.csvlog`) read a recording through a mapping file
(TOML). This module reads and checks the mapping, the tag and RSU maps it
names, and turns what an importer read into a :class:`~graphpos.drive.Drive`
(units, conventions, geodesy, time order); the importers only find the
values. Examples: ``examples/mapping_rosbag.toml``, ``examples/mapping_csv.toml``.

Format
------
``[drive]`` (optional):

- ``origin = { lat_deg = .., lon_deg = .., alt_m = .. }``: the WGS84 origin
  of the local east-north frame (alt_m optional, 0). Needed when GNSS gives
  latitude/longitude (they are placed in the frame by
  :func:`graphpos.io.geo.geodetic_to_enu`); otherwise it only places the
  drive on a map.
- ``tags = "tags.csv"``, ``rsus = "rsus.yaml"``: the tag (beacon, anchor) and
  RSU maps, CSV with a header line or YAML (a list of mappings), paths
  relative to the mapping file. Columns ``tag_id, east_m, north_m`` and
  optionally ``wall_side`` (+1 left, -1 right, 0, the default) and
  ``group`` (-1, the default); ``rsu_id, east_m, north_m``.

One section per drive channel (``[imu]``, ``[wheel]``, ``[compass]``,
``[rfid]``, ``[rsu]``, ``[gnss]``, ``[truth]``); a channel without a section
is not imported. Keys:

- ``topic = "/imu/data"`` (rosbag) or ``file = "imu.csv"`` (csv, relative to
  the folder given on the command line);
- ``type = "sensor_msgs/msg/Imu"`` (rosbag, optional): the topic's message
  type, ROS 2 ``pkg/msg/Type`` or ROS 1 ``pkg/Type``. The importer checks it
  against the bag; live rosbridge input (:mod:`graphpos.live.rosbridge`),
  which has no bag to read it from, takes it instead of an ``advertise``;
- ``fields = { input = "path", ... }``: where each input is (see
  :data:`INPUTS`): a message field path (``angular_velocity.z``,
  ``header.frame_id``, ``ranges[0].range``; ``ranges[*].range`` reads one
  row per element of an array) or a CSV column name; a number instead of a
  path is a constant; ``""`` drops an input a message type reads by
  default, and an input given replaces the defaults it is an alternative to
  (``sigma`` those of ``covariance``).
  The rosbag importer knows the usual fields of the common message types
  (:data:`graphpos.io.rosbag.DEFAULT_FIELDS`), so a section may name only
  its topic;
- ``units = { input = "unit" }``: the unit of an input (or of ``time``,
  ``arrival``) in the recording
  (:data:`UNITS`; default: the drive's SI unit, degrees for lat/lon);
- ``time``: rosbag: a field path to a ``Time`` or a number of seconds
  (default ``header.stamp`` where the message has a header), or
  ``"record"`` for the bag's record time; csv: the time column (required).
  Its unit is ``units.time``;
- ``arrival`` (rfid, rsu; csv only): the column of the arrival time (default:
  the measurement time). A bag's record time is always the arrival time;
- ``convention`` (compass, truth): ``"east_ccw"`` (yaw from east,
  counter-clockwise: the drive's; the default) or ``"north_cw"`` (heading
  from north, clockwise, as a compass gives it);
- ``ids = { "name" = 3 }`` (rfid, rsu): tag/RSU ids for the names a recording
  uses (e.g. ``header.frame_id``); without it an id must be a whole number;
- ``min_status`` (gnss): fixes whose ``status`` is below it are dropped
  (NavSatFix: -1 no fix, 0 fix, 1 SBAS, 2 GBAS; default 0);
- ``delimiter`` (csv): the cell separator (default ``","``).

The inputs of each channel (:data:`INPUTS`; [optional]):

=======  ====================================================================
imu      yaw_rate (rad/s); [accel_x and accel_y (m/s^2), forward and left]
wheel    speed (m/s), forward
compass  yaw (rad) or orientation (a quaternion)
rfid     tag_id; range (m) and/or rss; [bearing (rad): the tag's bearing
         from the body x axis, counter-clockwise, where the sensor gives one,
         as a camera does: its range error may depend on it, which
         graph-batch's self-calibration fits, :mod:`graphpos.profile`]
rsu      rsu_id; sigma (m); east and north (m) and/or range (m)
gnss     lat and lon (deg) [and alt (m), above the ellipsoid] or east and
         north (m); sigma (m, 1-sigma per axis) or covariance (NavSatFix's
         position_covariance: sigma = sqrt of the mean east/north variance);
         [status]
truth    east and north (m); yaw (rad) or orientation; [v_east and v_north,
         or v_forward and v_left (m/s, body frame); without them velocities
         are differentiated from the positions]; [yaw_rate (rad/s)]
=======  ====================================================================

Every value read is checked (a number, finite unless its drive column is
optional, ids whole; a compass yaw or tag bearing within +-4 pi in the
drive's unit, so that degrees read as radians are refused, suggesting the
unit, not wrapped into nonsense; a yaw rate in deg/s read as rad/s is
refused beyond the drive's +-10 rad/s); an error names the file or topic,
the row or message and the field. A recording's row (CSV) or message (bag) without a
required value (an empty cell, NaN) is a gap: dropped and counted
(:func:`build_drive`'s ``missing_as_gaps``). Rows are sorted by time
(stably); a row that repeats an earlier one exactly is dropped, rows of
one sensor at one time with other values are kept and noted. Compass yaw
and tag bearings are wrapped into (-pi, pi], truth yaw unwrapped.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from graphpos.drive import (CHANNEL_NAMES, CHANNEL_SPECS, RSU_SPECS, TAG_SPECS, Channel, Drive, GeoOrigin, RsuMap, TagMap,
                            truth_from_poses)
from graphpos.errors import ConfigError, DriveError, FileFormatError, is_finite_number
from graphpos.io.files import read_input
from graphpos.io.geo import geodetic_to_enu

#: Units a recording may use, by quantity: name -> factor to SI.
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9},
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "km": 1e3},
    "speed": {"m/s": 1.0, "km/h": 1 / 3.6, "mph": 0.44704},
    "acceleration": {"m/s^2": 1.0, "g": 9.80665},
    "angle": {"rad": 1.0, "deg": math.pi / 180},
    "angular_rate": {"rad/s": 1.0, "deg/s": math.pi / 180},
}

#: Heading conventions: ``east_ccw`` (yaw from east, counter-clockwise) or ``north_cw`` (from north, clockwise).
CONVENTIONS = ("east_ccw", "north_cw")


@dataclass(frozen=True)
class Input:
    """One quantity a channel reads from a recording.

    Parameters
    ----------
    kind : {"number", "id", "quaternion", "covariance"}
        A number; an integer id (or a name that ``ids`` turns into one); an
        orientation quaternion (a message's x, y, z, w); a 3x3 position
        covariance in m^2, row-major, east-north-up (a message's array of 9).
    quantity : str, optional
        Key of :data:`UNITS`; None for a value without a unit.
    unit : str, optional
        The unit the drive takes it in (the default of ``units``).
    optional : bool
        A row may lack it (NaN, an empty cell): its drive column is optional.
    max_si : float, optional
        The largest magnitude it can have in the drive's unit, whatever the
        recording: a value beyond it is in another unit (degrees read as
        radians), and the import is refused saying so. None: not checked
        here (a drive column's plausible range is checked on every channel,
        :data:`graphpos.drive.CHANNEL_SPECS`; this is for inputs wrapped
        before that check sees them).
    """

    kind: str = "number"
    quantity: str | None = None
    unit: str | None = None
    optional: bool = False
    max_si: float | None = None


#: Largest magnitude of a heading or bearing in radians, the drive's bound of a compass yaw (4 pi): a turn either
#: way of zero (0 .. 2 pi from north, -pi .. pi from east), doubled for one unwrapped for a while. Degrees (up to
#: 360) are far beyond it.
MAX_HEADING_RAD = next(spec.hi for spec in CHANNEL_SPECS["compass"] if spec.name == "yaw_rad")

_TIME = Input("number", "time", "s")
_LENGTH = Input("number", "length", "m")
_SOME_LENGTH = Input("number", "length", "m", optional=True)
_SPEED = Input("number", "speed", "m/s")
_ANGLE = Input("number", "angle", "rad")
_HEADING = Input("number", "angle", "rad", max_si=MAX_HEADING_RAD)
_GEODETIC = Input("number", "angle", "deg")
_QUATERNION = Input("quaternion")
_ID = Input("id")

#: What each channel reads, by input name (besides ``time`` and, for rfid and rsu, ``arrival``).
INPUTS: dict[str, dict[str, Input]] = {
    "imu": {"yaw_rate": Input("number", "angular_rate", "rad/s"),
            "accel_x": Input("number", "acceleration", "m/s^2", optional=True),
            "accel_y": Input("number", "acceleration", "m/s^2", optional=True)},
    "wheel": {"speed": _SPEED},
    "compass": {"yaw": _HEADING, "orientation": _QUATERNION},
    "rfid": {"tag_id": _ID, "range": _SOME_LENGTH, "rss": Input(optional=True),
             "bearing": Input("number", "angle", "rad", optional=True, max_si=MAX_HEADING_RAD)},
    "rsu": {"rsu_id": _ID, "east": _SOME_LENGTH, "north": _SOME_LENGTH, "range": _SOME_LENGTH, "sigma": _LENGTH},
    "gnss": {"lat": _GEODETIC, "lon": _GEODETIC, "alt": _LENGTH, "east": _LENGTH, "north": _LENGTH, "sigma": _LENGTH,
             "covariance": Input("covariance"), "status": Input()},
    "truth": {"east": _LENGTH, "north": _LENGTH, "yaw": _ANGLE, "orientation": _QUATERNION, "v_east": _SPEED,
              "v_north": _SPEED, "v_forward": _SPEED, "v_left": _SPEED,
              "yaw_rate": Input("number", "angular_rate", "rad/s", optional=True)},
}

#: Channels with an arrival time.
_ARRIVING = ("rfid", "rsu")

_NAME = r"[A-Za-z][A-Za-z0-9_]*"
#: A ROS message type: ``pkg/msg/Type`` (ROS 2) or ``pkg/Type`` (ROS 1).
_MSGTYPE = re.compile(rf"({_NAME})/(?:msg/)?({_NAME})")


@dataclass(frozen=True)
class _Need:
    """Alternatives (inputs given together) of which one must be given (``required``), and at most one unless ``several``."""

    options: tuple[tuple[str, ...], ...]
    required: bool = True
    several: bool = False


_NEEDS: dict[str, tuple[_Need, ...]] = {
    "imu": (_Need((("yaw_rate",),)), _Need((("accel_x", "accel_y"),), required=False)),
    "wheel": (_Need((("speed",),)),),
    "compass": (_Need((("yaw",), ("orientation",))),),
    "rfid": (_Need((("tag_id",),)), _Need((("range",), ("rss",)), several=True)),
    "rsu": (_Need((("rsu_id",),)), _Need((("sigma",),)), _Need((("east", "north"), ("range",)), several=True)),
    "gnss": (_Need((("lat", "lon"), ("east", "north"))), _Need((("sigma",), ("covariance",)))),
    "truth": (_Need((("east", "north"),)), _Need((("yaw",), ("orientation",))),
              _Need((("v_east", "v_north"), ("v_forward", "v_left")), required=False)),
}

#: Inputs that are a drive column as they are (after units), by input name.
_DIRECT = {"yaw_rate": "yaw_rate_radps", "accel_x": "accel_x_mps2", "accel_y": "accel_y_mps2", "speed": "speed_mps",
           "tag_id": "tag_id", "rsu_id": "rsu_id", "range": "range_m", "rss": "rss", "east": "east_m",
           "north": "north_m", "sigma": "sigma_m", "v_east": "v_east_mps", "v_north": "v_north_mps",
           "arrival": "arrival_s", "bearing": "bearing_rad"}

#: Section keys: common ones by source, and the channels a channel-specific key belongs to.
_SOURCE_KEYS = {"rosbag": ("topic", "type", "fields", "units", "time"),
                "csv": ("file", "fields", "units", "time", "delimiter")}
_CHANNEL_KEYS = {"convention": ("compass", "truth"), "ids": ("rfid", "rsu"), "min_status": ("gnss",)}
_CSV_CHANNEL_KEYS = {"arrival": _ARRIVING}
_DRIVE_KEYS = ("origin", "tags", "rsus")


def channel_inputs(channel: str) -> dict[str, Input]:
    """Every input of ``channel``, ``time`` (and ``arrival``) included."""
    return {**INPUTS[channel], "time": _TIME, **({"arrival": _TIME} if channel in _ARRIVING else {})}


@dataclass(frozen=True)
class ChannelMapping:
    """One channel's section of a mapping file (see the module docstring).

    Parameters
    ----------
    channel : str
        The drive channel.
    where : str
        The section, as an error names it (``mapping.toml [imu]``).
    source : str
        The topic (rosbag) or file name (csv).
    msgtype : str or None
        The topic's message type as ``pkg/msg/Type`` (rosbag ``type``); None: not given.
    fields : dict of str to str or float
        Input -> field path or column, or a constant (as the mapping gives them).
    units : dict of str to str
        Input -> unit in the recording.
    time : str or None
        Field path or column of the measurement time; ``"record"`` (rosbag); None: the default.
    arrival : str or None
        Column of the arrival time (csv).
    convention : str
        One of :data:`CONVENTIONS`.
    ids : dict of str to int
        Name -> id (rfid, rsu).
    min_status : int
        Lowest GNSS status kept.
    delimiter : str
        CSV cell separator.
    """

    channel: str
    where: str
    source: str
    fields: dict[str, str | float]
    msgtype: str | None = None
    units: dict[str, str] = field(default_factory=dict)
    time: str | None = None
    arrival: str | None = None
    convention: str = "east_ccw"
    ids: dict[str, int] = field(default_factory=dict)
    min_status: int = 0
    delimiter: str = ","

    def read_fields(self, defaults: dict[str, str] | None = None) -> dict[str, str | float]:
        """The inputs read: ``defaults`` (a message type's) with the mapping's fields over them, ``""`` dropped.

        A field the mapping gives replaces the defaults it is an alternative
        to (``sigma`` those of ``covariance``, ``yaw`` ``orientation`` ...).
        """
        fields = dict(defaults or {})
        for need in _NEEDS[self.channel]:
            chosen = [option for option in need.options if any(name in self.fields for name in option)]
            if chosen and not need.several:
                for name in (name for option in need.options if option not in chosen for name in option):
                    fields.pop(name, None)
        return {k: v for k, v in {**fields, **self.fields}.items() if v != ""}

    def factor(self, name: str) -> float:
        """Multiplier from the recording's unit of input ``name`` to the drive's."""
        spec = channel_inputs(self.channel)[name]
        if spec.quantity is None:
            return 1.0
        table = UNITS[spec.quantity]
        return table[self.units.get(name, spec.unit)] / table[spec.unit]


@dataclass(frozen=True)
class Mapping:
    """A mapping file, read and checked (:func:`load_mapping`).

    Parameters
    ----------
    path : Path
    channels : dict of str to ChannelMapping
        The channels to import, in the drive's channel order.
    origin : GeoOrigin or None
        The local frame's geodetic origin, when the mapping gives one.
    tags : TagMap
    rsus : RsuMap
    """

    path: Path
    channels: dict[str, ChannelMapping]
    origin: GeoOrigin | None
    tags: TagMap
    rsus: RsuMap


# ---------------------------------------------------------------------------
# Reading the mapping
# ---------------------------------------------------------------------------


def _table(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: expected a table, got {value!r}")
    return value


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: expected a non-empty string, got {value!r}")
    return value


def _finite(value: Any, where: str) -> float:
    if not is_finite_number(value):
        raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _whole(value: Any, where: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{where}: expected a whole number in [{lo}, {hi}], got {value!r}")
    return value


def ros_msgtype(value: Any, where: str) -> str:
    """A ROS message type, ROS 2 ``pkg/msg/Type`` or ROS 1 ``pkg/Type``, spelt ``pkg/msg/Type``.

    Raises
    ------
    ConfigError
        ``value`` is not such a name (naming ``where``).
    """
    match = _MSGTYPE.fullmatch(value) if isinstance(value, str) else None
    if match is None:
        raise ConfigError(f"{where}: expected a message type such as sensor_msgs/msg/Imu (ROS 2) or sensor_msgs/Imu "
                          f"(ROS 1), got {value!r}")
    return f"{match[1]}/msg/{match[2]}"


def _origin(value: Any, where: str) -> GeoOrigin:
    table = _table(value, where)
    unknown = set(table) - {"lat_deg", "lon_deg", "alt_m"}
    if unknown or not {"lat_deg", "lon_deg"} <= set(table):
        raise ConfigError(f"{where}: expected {{ lat_deg = .., lon_deg = .., alt_m = .. }} (alt_m optional), got {value!r}")
    try:
        return GeoOrigin(**{k: _finite(v, f"{where}.{k}") for k, v in table.items()})
    except DriveError as exc:
        raise ConfigError(f"{where}: {exc.reason}") from None


def _channel_section(channel: str, section: dict[str, Any], source_kind: str, where: str) -> ChannelMapping:
    allowed = [*_SOURCE_KEYS[source_kind],
               *(k for k, chans in {**_CHANNEL_KEYS, **(_CSV_CHANNEL_KEYS if source_kind == "csv" else {})}.items()
                 if channel in chans)]
    unknown = [k for k in section if k not in allowed]
    if unknown:
        raise ConfigError(f"{where}: unknown key '{unknown[0]}' (known here: {', '.join(allowed)})")
    source_key = _SOURCE_KEYS[source_kind][0]
    if source_key not in section:
        raise ConfigError(f"{where}: missing key '{source_key}'")
    inputs = channel_inputs(channel)
    fields: dict[str, str | float] = {}
    for name, value in _table(section.get("fields", {}), f"{where} fields").items():
        if name not in INPUTS[channel]:
            raise ConfigError(f"{where} fields: unknown input '{name}' (known: {', '.join(INPUTS[channel])}; "
                              "the time is the key 'time')")
        if isinstance(value, str):
            fields[name] = value
        elif INPUTS[channel][name].kind == "number":
            fields[name] = _finite(value, f"{where} fields.{name}")
        elif INPUTS[channel][name].kind == "id":
            fields[name] = float(_whole(value, f"{where} fields.{name}", 0, 2**53))
        else:
            raise ConfigError(f"{where} fields.{name}: expected a field path, got {value!r}")
    units: dict[str, str] = {}
    for name, value in _table(section.get("units", {}), f"{where} units").items():
        spec = inputs.get(name)
        if spec is None or spec.quantity is None:
            with_units = [k for k, s in inputs.items() if s.quantity is not None]
            what = "takes no unit" if spec else f"is not an input of [{channel}]"
            raise ConfigError(f"{where} units: '{name}' {what} (inputs with units: {', '.join(with_units)})")
        if value not in UNITS[spec.quantity]:
            raise ConfigError(f"{where} units.{name}: unknown {spec.quantity.replace('_', ' ')} unit {value!r} "
                              f"(known: {', '.join(UNITS[spec.quantity])})")
        units[name] = value
    convention = section.get("convention", CONVENTIONS[0])
    if convention not in CONVENTIONS:
        raise ConfigError(f"{where} convention: expected one of {', '.join(CONVENTIONS)}, got {convention!r}")
    ids = {k: _whole(v, f"{where} ids.{k}", 0, 2**53) for k, v in _table(section.get("ids", {}), f"{where} ids").items()}
    delimiter = section.get("delimiter", ",")
    if not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in "\"\r\n":
        raise ConfigError(f"{where} delimiter: expected one character (not a quote or a line break), got {delimiter!r}")
    return ChannelMapping(
        channel=channel, where=where, source=_text(section[source_key], f"{where} {source_key}"), fields=fields,
        msgtype=ros_msgtype(section["type"], f"{where} type") if "type" in section else None, units=units,
        time=_text(section["time"], f"{where} time") if "time" in section else None,
        arrival=_text(section["arrival"], f"{where} arrival") if "arrival" in section else None,
        convention=convention, ids=ids, min_status=_whole(section.get("min_status", 0), f"{where} min_status", -1, 2),
        delimiter=delimiter)


def check_inputs(cm: ChannelMapping, fields: dict[str, str | float], origin: GeoOrigin | None) -> None:
    """Check that the inputs read for a channel make sense together.

    Parameters
    ----------
    cm : ChannelMapping
    fields : dict
        The inputs read (:meth:`ChannelMapping.read_fields`).
    origin : GeoOrigin or None
        The mapping's origin (needed to place latitude/longitude).

    Raises
    ------
    ConfigError
        An input missing, one given without its partner, alternatives
        mixed, a unit for an input not read, lat/lon without an origin.
    """
    for need in _NEEDS[cm.channel]:
        given = [option for option in need.options if any(name in fields for name in option)]
        for option in given:
            missing = [name for name in option if name not in fields]
            if missing:
                raise ConfigError(f"{cm.where}: {' and '.join(option)} go together; '{missing[0]}' is not given")
        alternatives = " or ".join("+".join(option) for option in need.options)
        if need.required and not given:
            raise ConfigError(f"{cm.where}: no field gives {alternatives} (set it in fields)")
        if len(given) > 1 and not need.several:
            raise ConfigError(f"{cm.where}: give one of {alternatives}, not several")
    unread = [name for name in cm.units if name not in fields and not (name == "time" or (name == "arrival" and cm.arrival))]
    if unread:
        raise ConfigError(f"{cm.where} units: '{unread[0]}' is not read (no field gives it)")
    if "lat" in fields and origin is None:
        raise ConfigError(f"{cm.where}: latitude/longitude need [drive] origin = {{ lat_deg = .., lon_deg = .. }} "
                          "to be placed in the local east-north frame")


def load_mapping(path: str | os.PathLike, source_kind: str) -> Mapping:
    """Read and check a mapping file (format: module docstring).

    Parameters
    ----------
    path : path-like
        The TOML file.
    source_kind : {"rosbag", "csv"}
        The importer it is for (which keys it takes).

    Raises
    ------
    FileFormatError
        The mapping, tag or RSU file cannot be read.
    ConfigError
        A section, key or value is wrong: one line naming the file, section and key.
    DriveError
        The tag or RSU map is invalid (naming its file).
    """
    path = Path(path)
    try:
        document = tomllib.loads(read_input(path).decode("utf-8"))
    except UnicodeDecodeError:
        raise FileFormatError(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    unknown = [k for k in document if k not in ("drive", *CHANNEL_NAMES)]
    if unknown:
        raise ConfigError(f"{path}: unknown section [{unknown[0]}] (known: drive, {', '.join(CHANNEL_NAMES)})")
    drive = _table(document.get("drive", {}), f"{path} [drive]")
    unknown = [k for k in drive if k not in _DRIVE_KEYS]
    if unknown:
        raise ConfigError(f"{path} [drive]: unknown key '{unknown[0]}' (known: {', '.join(_DRIVE_KEYS)})")
    origin = _origin(drive["origin"], f"{path} [drive] origin") if "origin" in drive else None
    channels = {name: _channel_section(name, _table(document[name], f"{path} [{name}]"), source_kind, f"{path} [{name}]")
                for name in CHANNEL_NAMES if name in document}
    if not channels:
        raise ConfigError(f"{path}: no channel section (give at least one of {', '.join(f'[{c}]' for c in CHANNEL_NAMES)})")
    for channel, key in (("rfid", "tags"), ("rsu", "rsus")):
        if channel in channels and key not in drive:
            raise ConfigError(f"{path} [{channel}]: readings need a map: set [drive] {key} = \"FILE.csv\" (or .yaml)")
    if source_kind == "csv":
        for cm in channels.values():
            if cm.time is None:
                raise ConfigError(f"{cm.where}: missing key 'time' (the column of the measurement time)")
            kinds = [n for n, v in cm.fields.items() if isinstance(v, str) and INPUTS[cm.channel][n].kind in ("quaternion", "covariance")]
            if kinds:
                raise ConfigError(f"{cm.where} fields.{kinds[0]}: a CSV column holds one number; "
                                  f"give {'yaw' if kinds[0] == 'orientation' else 'sigma'} instead")
            check_inputs(cm, cm.read_fields(), origin)
    maps = {}
    for key in ("tags", "rsus"):
        if key in drive:
            try:
                maps[key] = _load_map(path.parent / _text(drive[key], f"{path} [drive] {key}"), key)
            except FileFormatError as exc:
                raise FileFormatError(f"{path} [drive] {key}: {exc}") from None
    return Mapping(path=path, channels=channels, origin=origin, tags=maps.get("tags", TagMap.empty()),
                   rsus=maps.get("rsus", RsuMap.empty()))


# ---------------------------------------------------------------------------
# Tables: CSV files and the tag/RSU maps
# ---------------------------------------------------------------------------


def read_csv_table(path: Path, delimiter: str = ",") -> tuple[list[str], list[list[str]], list[int]]:
    """The header, the rows and each row's line number of a CSV file.

    UTF-8 (a byte-order mark is skipped); blank lines are skipped; every
    row must have as many cells as the header.

    Raises
    ------
    FileFormatError
        Unreadable, not UTF-8, no header, a row of the wrong length, a
        header naming a column twice.
    """
    try:
        text = read_input(path).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise FileFormatError(f"{path}: not UTF-8 text") from None
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
    rows, lines = [], []
    try:
        header = [name.strip() for name in next(reader, [])]
        for row in reader:
            if not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                raise FileFormatError(f"{path}, line {reader.line_num}: {len(row)} cells, the header has {len(header)}")
            rows.append(row)
            lines.append(reader.line_num)
    except csv.Error as exc:
        raise FileFormatError(f"{path}, line {reader.line_num}: not CSV ({exc})") from None
    if not any(header):
        raise FileFormatError(f"{path}: no header line naming the columns")
    twice = [name for name in header if header.count(name) > 1]
    if twice:
        raise FileFormatError(f"{path}: column '{twice[0]}' is named twice in the header")
    return header, rows, lines


def parse_number(value: Any) -> float:
    """A cell or field value as a float: a number, or text of one (empty text: NaN).

    Raises
    ------
    ValueError
        With the reason, for anything else.
    """
    if isinstance(value, str):
        text = value.strip()
        if not text:
            return math.nan
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{value!r} is not a number") from None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise ValueError(f"{value!r} is not a number")
    return float(value)


#: Columns of the map files and their defaults where optional.
_MAP_COLUMNS = {"tags": (TAG_SPECS, {"wall_side": 0.0, "group": -1.0}), "rsus": (RSU_SPECS, {})}


def _map_records(path: Path) -> list[tuple[str, dict[str, Any]]]:
    """The rows of a CSV or YAML map file, each with the words naming it."""
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            document = yaml.safe_load(read_input(path).decode("utf-8"))
        except (UnicodeDecodeError, yaml.YAMLError) as exc:
            raise FileFormatError(f"{path}: not YAML text ({' '.join(str(exc).split())})") from None
        if not isinstance(document, list) or not all(isinstance(entry, dict) for entry in document):
            raise FileFormatError(f"{path}: expected a YAML list of mappings, one per tag or RSU")
        return [(f"entry {i}", {str(k): v for k, v in entry.items()}) for i, entry in enumerate(document)]
    if path.suffix.lower() != ".csv":
        raise FileFormatError(f"{path}: a map file is .csv or .yaml/.yml")
    header, rows, lines = read_csv_table(path)
    return [(f"line {line}", dict(zip(header, row))) for row, line in zip(rows, lines)]


def _load_map(path: Path, kind: str) -> TagMap | RsuMap:
    """A tag or RSU map file (columns: :data:`graphpos.drive.TAG_SPECS` / ``RSU_SPECS``)."""
    specs, defaults = _MAP_COLUMNS[kind]
    names = [spec.name for spec in specs]
    columns: dict[str, list[float]] = {name: [] for name in names}
    for row_name, record in _map_records(path):
        unknown = [k for k in record if k not in names]
        missing = [n for n in names if n not in record and n not in defaults]
        if unknown or missing:
            problem = f"unknown column '{unknown[0]}'" if unknown else f"missing column '{missing[0]}'"
            raise FileFormatError(f"{path}, {row_name}: {problem} (columns: {', '.join(names)}; "
                                  f"optional: {', '.join(defaults) or 'none'})")
        for name in names:
            value = record.get(name, defaults.get(name))
            try:
                number = parse_number(value)
            except ValueError as exc:
                raise FileFormatError(f"{path}, {row_name}, column '{name}': {exc}") from None
            if not math.isfinite(number):
                raise FileFormatError(f"{path}, {row_name}, column '{name}': {value!r} is not a finite number")
            columns[name].append(number)
    try:
        return TagMap(*columns.values()) if kind == "tags" else RsuMap(*columns.values())
    except DriveError as exc:
        raise exc.with_source(str(path)) from None


# ---------------------------------------------------------------------------
# What an importer read -> a drive
# ---------------------------------------------------------------------------


@dataclass
class RawChannel:
    """What an importer read for one channel, before units and conventions.

    Parameters
    ----------
    mapping : ChannelMapping
    source : str
        The file or topic, as an error names it.
    fields : dict of str to str or float
        Input -> field path or column (a float: a constant of the mapping).
    values : dict of str to sequence
        Input -> one raw value per row (numbers, text, quaternions (x, y,
        z, w), covariance arrays) for every input read from the recording.
    row_name : callable
        Row index -> the words naming it (``message 3 (recorded at .. s)``, ``line 5``).
    field_word : str
        ``field`` or ``column``.
    """

    mapping: ChannelMapping
    source: str
    fields: dict[str, str | float]
    values: dict[str, Sequence[Any]]
    row_name: Callable[[int], str]
    field_word: str

    def error(self, row: int, name: str, reason: str) -> FileFormatError:
        """A one-line error on input ``name`` of ``row``."""
        return FileFormatError(f"{self.source}, {self.row_name(row)}, {self.field_word} '{self.fields[name]}' ({name}): {reason}")

    def __len__(self) -> int:
        return len(self.values["time"])


def _numbers(raw: RawChannel, rows: np.ndarray, name: str, optional: bool) -> np.ndarray:
    values = raw.values[name]
    picked = [values[r] for r in rows.tolist()]
    try:
        out = np.asarray(picked, dtype=np.float64)
    except (TypeError, ValueError):
        out = np.empty(rows.size)
        for i, (row, value) in enumerate(zip(rows.tolist(), picked)):
            try:
                out[i] = parse_number(value)
            except ValueError as exc:
                raise raw.error(row, name, str(exc)) from None
    bad = np.isinf(out) if optional else ~np.isfinite(out)
    if bad.any():
        i = int(np.argmax(bad))
        value = picked[i]
        what = "is empty" if isinstance(value, str) and not value.strip() else f"{value!r} is not a finite number"
        raise raw.error(int(rows[i]), name, what)
    return out


def _ids(raw: RawChannel, rows: np.ndarray, name: str) -> np.ndarray:
    table = raw.mapping.ids
    out = np.empty(rows.size)
    for i, row in enumerate(rows.tolist()):
        value = raw.values[name][row]
        if table:
            key = value.strip() if isinstance(value, str) else str(int(value)) if float(value).is_integer() else repr(value)
            if key not in table:
                raise raw.error(row, name, f"{key!r} is not in ids (known: {', '.join(table)})")
            out[i] = table[key]
            continue
        try:
            number = parse_number(value)
        except ValueError as exc:
            raise raw.error(row, name, f"{exc}; map names to ids with ids = {{ \"name\" = 1 }}") from None
        if not (math.isfinite(number) and number >= 0 and number.is_integer()):
            raise raw.error(row, name, f"{value!r} is not a whole number >= 0")
        out[i] = number
    return out


def _arrays(raw: RawChannel, rows: np.ndarray, name: str, width: int) -> np.ndarray:
    """(rows, width) array of an input read as a sequence (quaternion, covariance), checked finite."""
    picked = [raw.values[name][r] for r in rows.tolist()]
    out = np.asarray(picked, dtype=np.float64)[:, :width] if picked else np.zeros((0, width))
    bad = ~np.isfinite(out).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise raw.error(int(rows[i]), name, f"{list(out[i])} is not finite")
    return out


def _check_magnitude(raw: RawChannel, rows: np.ndarray, name: str, values_si: np.ndarray) -> None:
    """Refuse values of input ``name`` beyond its :attr:`Input.max_si`: they are in another unit than the mapping says.

    The error names the first such row and suggests the unit of :data:`UNITS` the column's values fit in.
    """
    spec = channel_inputs(raw.mapping.channel)[name]
    if spec.max_si is None:
        return
    beyond = np.abs(values_si) > spec.max_si  # NaN (a gap, an optional value absent) is not beyond
    if not beyond.any():
        return
    cm = raw.mapping
    table = UNITS[spec.quantity]
    unit = cm.units.get(name, spec.unit)
    to_recorded = table[spec.unit] / table[unit]
    largest = float(np.nanmax(np.abs(values_si))) * to_recorded
    fitting = [u for u, factor in table.items() if u != unit and largest * factor / table[spec.unit] <= spec.max_si]
    advice = (f"in {fitting[0]}? set units = {{ {name} = \"{fitting[0]}\" }}" if fitting else f"check units.{name}")
    i = int(np.argmax(beyond))
    raise raw.error(int(rows[i]), name, f"{values_si[i] * to_recorded:g} is beyond ±{spec.max_si * to_recorded:.4g} "
                                        f"{unit}, which no {name.replace('_', ' ')} in {unit} reaches (the "
                                        f"{raw.field_word} reaches {largest:g}); {advice} in {cm.where}")


def input_values(raw: RawChannel, rows: np.ndarray, name: str) -> np.ndarray:
    """Input ``name`` of the given rows in the drive's unit (an id as its number, a quaternion as its yaw, a
    covariance as sigma).

    Raises
    ------
    FileFormatError
        A value that is not a number, not finite, not a whole id, not in ``ids``, or beyond what the input can
        be in the mapping's unit (:attr:`Input.max_si`) (:meth:`RawChannel.error`).
    """
    spec = channel_inputs(raw.mapping.channel)[name]
    value = raw.fields[name]
    if not isinstance(value, str):
        return np.full(rows.size, value * raw.mapping.factor(name))
    if spec.kind == "id":
        return _ids(raw, rows, name)
    if spec.kind == "quaternion":
        xyzw = _arrays(raw, rows, name, 4)
        zero = np.linalg.norm(xyzw, axis=1) < 1e-9
        if zero.any():
            raise raw.error(int(rows[np.argmax(zero)]), name, "the quaternion is zero")
        return Rotation.from_quat(xyzw).as_euler("ZYX")[:, 0]
    if spec.kind == "covariance":
        cov = _arrays(raw, rows, name, 5)
        var_en_m2 = cov[:, [0, 4]]
        bad = ~(var_en_m2 > 0).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise raw.error(int(rows[i]), name, f"east/north variances {var_en_m2[i, 0]:g}, {var_en_m2[i, 1]:g} "
                                                "are not positive (unknown?); give fields.sigma instead")
        return np.sqrt(var_en_m2.mean(axis=1))
    values_si = _numbers(raw, rows, name, spec.optional) * raw.mapping.factor(name)
    _check_magnitude(raw, rows, name, values_si)
    return values_si


def _yaw_rad(cm: ChannelMapping, get: Callable[[str], np.ndarray | None]) -> np.ndarray:
    """Yaw from east, counter-clockwise, of the ``yaw`` or ``orientation`` input in the mapping's convention."""
    yaw = get("yaw")
    yaw = get("orientation") if yaw is None else yaw
    return yaw if cm.convention == "east_ccw" else np.pi / 2 - yaw


def _columns(raw: RawChannel, get: Callable[[str], np.ndarray | None], origin: GeoOrigin | None) -> dict[str, np.ndarray]:
    """The drive columns of a channel from its inputs (``get``: an input in the drive's unit, time-sorted; None if not read)."""
    cm = raw.mapping
    names = {spec.name for spec in CHANNEL_SPECS[cm.channel]}
    cols = {"t_s": get("time"), **{column: get(name) for name, column in _DIRECT.items()
                                   if column in names and name in raw.fields}}
    if cm.channel == "compass":
        cols["yaw_rad"] = np.angle(np.exp(1j * _yaw_rad(cm, get)))  # wrapped into (-pi, pi]
    if cols.get("bearing_rad") is not None:
        cols["bearing_rad"] = np.angle(np.exp(1j * cols["bearing_rad"]))  # a 0-360 degree log too; NaN stays NaN
    if cm.channel == "gnss":
        if "lat" in raw.fields:
            cols["east_m"], cols["north_m"], _ = geodetic_to_enu(get("lat"), get("lon"), origin, get("alt"))
        if "covariance" in raw.fields:
            cols["sigma_m"] = get("covariance")
    if cm.channel == "truth":
        yaw = np.unwrap(_yaw_rad(cm, get))
        cols["yaw_rad"] = yaw
        if "v_forward" in raw.fields:  # body frame (x forward, y left) -> east/north
            forward, left = get("v_forward"), get("v_left")
            cols["v_east_mps"] = forward * np.cos(yaw) - left * np.sin(yaw)
            cols["v_north_mps"] = forward * np.sin(yaw) + left * np.cos(yaw)
        elif "v_east" not in raw.fields:
            if yaw.size < 2:
                raise FileFormatError(f"{raw.source}: {yaw.size} pose(s); velocities from positions need at least 2")
            poses = truth_from_poses(cols["t_s"], cols["east_m"], cols["north_m"], yaw)
            cols.update(v_east_mps=poses.v_east_mps, v_north_mps=poses.v_north_mps)
    return cols


def _located(exc: DriveError, raw: RawChannel, rows: np.ndarray) -> FileFormatError:
    """A drive model's complaint about a channel row, naming the recording's row."""
    where = raw.source if exc.row is None else f"{raw.source}, {raw.row_name(int(rows[exc.row]))}"
    return FileFormatError(f"{where}: {exc.reason}")


def _without_gaps(raw: RawChannel, rows: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The rows whose every required number (not the time) has a value, and a note on the others (gaps: NaN, empty).

    Raises
    ------
    FileFormatError
        A value that is not a number, or infinite (:func:`_numbers`).
    """
    inputs = channel_inputs(raw.mapping.channel)
    gap = np.zeros(rows.size, dtype=bool)
    said = []
    for name, source in raw.fields.items():
        spec = inputs[name]
        if not isinstance(source, str) or spec.kind != "number" or spec.optional or spec.quantity == "time":
            continue
        missing = np.isnan(_numbers(raw, rows, name, optional=True))
        if missing.any():
            said.append(f"{raw.field_word} '{source}' ({name}): {int(np.count_nonzero(missing))}, first "
                        f"{raw.row_name(int(rows[np.argmax(missing)]))}")
            gap |= missing
    if not gap.any():
        return rows, []
    return rows[~gap], [f"{raw.source}: {int(np.count_nonzero(gap))} of {rows.size} rows have no value (NaN or "
                        f"empty) where one is needed ({'; '.join(said)}): gaps in that sensor; dropped"]


def _without_repeats(raw: RawChannel, channel: Channel, rows: np.ndarray) -> tuple[Channel, np.ndarray, list[str]]:
    """The channel without rows that repeat an earlier row exactly, its rows, and notes on the repeats and on rows
    at the time of another with other values (kept: :func:`graphpos.io.checks.repeated_rows`)."""
    from graphpos.io.checks import repeated_rows

    notes = []
    exact = repeated_rows(channel)[0]
    if exact.any():
        notes.append(f"{raw.source}: {int(np.count_nonzero(exact))} of {rows.size} rows repeat an earlier row exactly "
                     f"(first: {raw.row_name(int(rows[np.argmax(exact)]))}); dropped")
        channel, rows = channel.select(~exact), rows[~exact]
    conflicting = repeated_rows(channel)[1]
    if conflicting.any():
        i = int(np.argmax(conflicting))
        notes.append(f"{raw.source}: {int(np.count_nonzero(conflicting))} of {rows.size} rows are at the time of the "
                     f"row before with other values (first: {raw.row_name(int(rows[i]))}, at the time of "
                     f"{raw.row_name(int(rows[i - 1]))}, t = {channel.t_s[i]:.6g} s): two readings at one instant "
                     "(each row logged twice? two sensors in one file?); both kept")
    return channel, rows, notes


def _build_channel(raw: RawChannel, origin: GeoOrigin | None, missing_as_gaps: bool) -> tuple[Channel, np.ndarray, list[str]]:
    """A channel from what was read, the recording's row of each of its rows, and notes on what was changed
    (``missing_as_gaps``: :func:`build_drive`)."""
    cm = raw.mapping
    rows = np.arange(len(raw))
    notes = []
    if "status" in raw.fields:
        keep = input_values(raw, rows, "status") >= cm.min_status
        if not keep.all():
            notes.append(f"{raw.source}: {int(np.count_nonzero(~keep))} of {rows.size} fixes have a status below "
                         f"min_status {cm.min_status}; dropped")
        rows = rows[keep]
    if missing_as_gaps:
        rows, found = _without_gaps(raw, rows)
        notes += found
    t_s = input_values(raw, rows, "time")
    order = np.argsort(t_s, kind="stable")
    moved = int(np.count_nonzero(order != np.arange(order.size)))
    if moved:
        notes.append(f"{raw.source}: {moved} rows were out of time order; sorted")
    rows = rows[order]
    read = {"time": t_s[order]}

    def get(name: str) -> np.ndarray | None:
        if name not in raw.fields:
            return None
        if name not in read:
            read[name] = input_values(raw, rows, name)
        return read[name]

    try:
        channel = Channel(cm.channel, _columns(raw, get, origin))
    except DriveError as exc:
        raise _located(exc, raw, rows) from None
    channel, rows, found = _without_repeats(raw, channel, rows)
    return channel, rows, notes + found


def build_drive(mapping: Mapping, raws: Sequence[RawChannel], name: str, params: dict[str, Any],
                missing_as_gaps: bool = True) -> Drive:
    """The drive from what an importer read through ``mapping``.

    Rows that repeat an earlier row of their channel exactly are dropped;
    rows of one sensor at one time with other values are kept and noted
    (:func:`graphpos.io.checks.repeated_rows`; the drive check
    ``conflicting-rows`` warns of them too).

    Parameters
    ----------
    mapping : Mapping
    raws : sequence of RawChannel
        One per channel of the mapping.
    name : str
        The drive's name.
    params : dict
        Provenance; ``import_notes`` is added where rows were dropped or reordered, or repeat a time.
    missing_as_gaps : bool
        True (recordings: CSV logs, bags): a row without a value (NaN, an
        empty cell) for a required input other than the time is a gap in
        that sensor, dropped and counted in a note (README: non-finite
        samples are gaps). False: refused, as a message of a live feed is
        (:mod:`graphpos.live.rosbridge`, which takes it for malformed).

    Raises
    ------
    FileFormatError
        A value that is not a number, infinite, NaN (unless
        ``missing_as_gaps``), not a whole id, beyond what its unit allows
        (:attr:`Input.max_si`), outside the drive's bounds, or an id not in
        the map: naming the file or topic, the row or message and the field.
    """
    channels, sources, notes = {}, {}, []
    for raw in raws:
        channel, rows, found = _build_channel(raw, mapping.origin, missing_as_gaps)
        channels[channel.kind] = channel
        sources[channel.kind] = (raw, rows)
        notes += found
    if notes:
        params = {**params, "import_notes": notes}
    try:
        return Drive(name=name, channels=channels, tags=mapping.tags, rsus=mapping.rsus,
                     origin=mapping.origin or GeoOrigin(), params=params)
    except DriveError as exc:
        if exc.channel in sources:
            raise _located(exc, *sources[exc.channel]) from None
        raise
