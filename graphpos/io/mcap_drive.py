"""Drives and estimates in MCAP files.

One drive is one MCAP file (zstd chunks, message indexes, summary with
statistics and chunk index; :mod:`graphpos.io.mcap_container` writes and
walks the container). Every message is JSON (message encoding ``json``,
schema encoding ``jsonschema``), so Foxglove opens the file as it is and
another tool can write a file :func:`read_drive` reads.

File layout
-----------
Lossless topics (what :func:`read_drive` and :func:`read_estimates` decode,
recognised by their *schema name*, not their topic):

========================  =======================  ===============================
topic                     schema                   one message per
========================  =======================  ===============================
``/imu`` ``/wheel`` ...   ``graphpos.<channel>``   row of that channel; the fields
                                                   are the channel's columns
                                                   (:data:`~graphpos.drive.CHANNEL_SPECS`)
``/estimates/<name>``     ``graphpos.estimate``    output epoch of an estimator
========================  =======================  ===============================

An estimate's channel metadata holds the estimator's name, which optional
fields it estimates, its nominal rate, wall time and diagnostics (JSON).

A float is written with Python's shortest round-trip representation, so
float64 values come back bit-exact; NaN is written as ``null`` and +-inf as
``1e999``/``-1e999`` (valid JSON that parses back to +-inf). Integer columns
(``tag_id``, ``rsu_id``) are JSON integers. Unknown fields are ignored on
reading; a missing or null required field is an error naming the row, and
so is a field of the wrong JSON type (a string, a boolean, an array where a
number belongs: never coerced, :mod:`graphpos.io.json_rules`). Messages
are decoded with msgspec, straight into a table of numbers where every
message's fields are numbers or null (:func:`_number_table`); whatever
msgspec refuses goes to the standard library's parser
(:func:`_decode_messages`), so values and errors are json's bit for bit.

Viewing topics (Foxglove well-known schemas, written for people, never read
back):

- ``/truth/fix``, ``/gnss/fix``, ``/rsu/fix``, ``/estimates/<name>/fix``:
  ``foxglove.LocationFix`` (latitude/longitude from east/north by
  :func:`graphpos.io.geo.enu_to_geodetic` about the drive's origin, so the
  Map panel draws the track; GNSS and RSU fixes carry their sigma as a
  diagonal covariance; the fixes of the truth and of each estimate carry
  their colour, :func:`graphpos.colors.color_of`, the one of the report
  plots, so that the Map panel tells the tracks apart);
- ``/truth/pose``, ``/estimates/<name>/pose``: ``foxglove.PoseInFrame`` in
  frame ``enu`` (x east, y north, yaw about z);
- ``/map``: one ``foxglove.GeoJSON`` message with the tags and RSUs as points.

Truth and estimate views are thinned to at most :data:`VIEW_RATE_HZ` (the
first sample of each 1/VIEW_RATE_HZ s bin): they are for the eye and the
lossless topics hold every row.

Everything that is not a time series is in the metadata record
``graphpos.drive``: format version, name, origin, params (JSON), windows,
tag map with layouts, RSU map. A file without that record (e.g. written by
another tool) still reads: the drive is named after the file and has empty
maps and the default origin. Each key of the record is checked on reading
against :data:`graphpos.io.json_rules.DRIVE_METADATA_RULES` (JSON types,
the params graphpos reads) and then by the drive's classes (values); a bad
one is refused in one line naming the file, the field and the value.

Times: message log and publish times are the measurement time ``t_s`` in
integer nanoseconds, shifted by ``time_base_s`` (metadata; 0 unless the
drive has negative times) and clipped to the uint64 range. They order the
file and drive the viewer; the exact float seconds are in each message's
``t_s`` field (and ``arrival_s`` for late readings). On reading, each
channel's rows keep the order of its messages in the file, with one
exception: in a file ``graphpos live`` wrote (the header's library starts
with ``graphpos live``), a channel with an ``arrival_s`` field (``rfid``,
``rsu``) whose rows are in arrival order (``t_s`` goes back at a late
reading while ``arrival_s`` never does, as the recorder writes them) is
sorted stably by ``t_s``. Any other channel whose ``t_s`` goes back is
refused: :func:`write_drive` and the importers write every channel in
``t_s`` order, so there it is damage, not a late reading.

Writing row by row
------------------
``graphpos live`` records as it runs (:mod:`graphpos.io.mcap_recorder`)
with the encoders :func:`write_drive` uses, one row at a time:
:func:`channel_schema`, :func:`encode_row`, :func:`estimate_schema`,
:func:`encode_estimate_row`, :func:`estimate_channel_metadata`,
:func:`drive_metadata`, :func:`log_time_ns`, and the viewing messages
:func:`location_fix_payload` (:data:`LOCATION_FIX_SCHEMA`),
:func:`pose_payload` (:data:`POSE_IN_FRAME_SCHEMA`) and
:func:`map_geojson_payload` (:data:`GEOJSON_SCHEMA`). A recording that was
never closed reads up to its last complete chunk, its drive's params
marked ``"unclosed_recording": True`` (:func:`read_drive`).
"""

from __future__ import annotations

import functools
import itertools
import json
import json.scanner
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from mcap.records import Channel as McapChannel

from graphpos import __version__
from graphpos.colors import rgb_of
from graphpos.drive import CHANNEL_SPECS, Channel, ColumnSpec, Drive, GeoOrigin, RsuMap, TagMap, Window
from graphpos.errors import ConfigError, DriveError, FileFormatError
from graphpos.estimate import Estimate, OutputRow
from graphpos.io.json_rules import (DRIVE_METADATA_RULES, ESTIMATE_METADATA_RULES, JsonRuleError, Rule, check_value,
                                    number_column, number_rows)
from graphpos.io.mcap_container import LIVE_LIBRARY, McapContents, Topic, read_mcap_contents, write_mcap

#: Format written in the ``graphpos.drive`` metadata record.
FORMAT_NAME = "graphpos.drive"
FORMAT_VERSION = 1
#: Maximum rate of the viewing topics of truth and estimates.
VIEW_RATE_HZ = 10.0
#: Frame of the pose topics.
POSE_FRAME = "enu"

_ESTIMATE_SCHEMA = "graphpos.estimate"
_ESTIMATE_FIELDS = ("t_s", "east_m", "north_m", "v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2")
_OPTIONAL_ESTIMATE_FIELDS = ("v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2")
_MAX_UINT64_NS = 1.8e19
_BATCH_ROWS = 50_000  # rows encoded or decoded at a time (bounds the per-value Python objects alive)


def _schema_name(kind: str) -> str:
    return f"graphpos.{kind}"


_KIND_BY_SCHEMA = {_schema_name(kind): kind for kind in CHANNEL_SPECS}


def _specs_of(kind: str) -> tuple[ColumnSpec, ...]:
    """The column specs of channel ``kind``; DriveError for an unknown channel."""
    if kind not in CHANNEL_SPECS:
        raise DriveError(kind, None, f"unknown channel (known: {', '.join(CHANNEL_SPECS)})")
    return CHANNEL_SPECS[kind]


# ---------------------------------------------------------------------------
# JSON schemas
# ---------------------------------------------------------------------------


def channel_schema(kind: str) -> dict[str, Any]:
    """The JSON schema of the messages of channel ``kind`` (its ``title`` is
    the schema name, ``graphpos.<kind>``).

    Raises
    ------
    DriveError
        An unknown channel.
    """
    specs = _specs_of(kind)
    props = {}
    for spec in specs:
        if spec.integer:
            props[spec.name] = {"type": "integer", "minimum": spec.lo, "maximum": spec.hi}
        elif spec.required:
            props[spec.name] = {"type": "number", "minimum": spec.lo, "maximum": spec.hi}
        else:
            props[spec.name] = {"type": ["number", "null"], "description": "null where the source does not give it"}
    return {
        "title": _schema_name(kind),
        "description": f"One row of the graphpos '{kind}' channel (units in the field names).",
        "type": "object",
        "properties": props,
        "required": [s.name for s in specs if s.required],
    }


def estimate_schema() -> dict[str, Any]:
    """The JSON schema of the messages of an estimate (schema name ``graphpos.estimate``)."""
    nullable = {"type": ["number", "null"]}
    return {
        "title": _ESTIMATE_SCHEMA,
        "description": "One output epoch of a graphpos estimator; null where it does not estimate the quantity.",
        "type": "object",
        "properties": {
            "t_s": {"type": "number"},
            "east_m": {"type": "number"},
            "north_m": {"type": "number"},
            "v_east_mps": nullable,
            "v_north_mps": nullable,
            "yaw_rad": nullable,
            "cov_en_m2": {
                "type": ["array", "null"],
                "items": {"type": ["number", "null"]},
                "minItems": 4,
                "maxItems": 4,
                "description": "east/north position covariance, row-major [ee, en, ne, nn]",
            },
        },
        "required": ["t_s", "east_m", "north_m"],
    }


_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
}
#: Foxglove's well-known location fix schema (the fields graphpos writes).
LOCATION_FIX_SCHEMA = {
    "title": "foxglove.LocationFix",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "latitude": {"type": "number"},
        "longitude": {"type": "number"},
        "altitude": {"type": "number"},
        "position_covariance": {"type": "array", "items": {"type": "number"}, "minItems": 9, "maxItems": 9},
        "position_covariance_type": {"type": "integer", "minimum": 0, "maximum": 3},
        "color": {
            "title": "foxglove.Color",
            "type": "object",
            "properties": {k: {"type": "number", "minimum": 0, "maximum": 1} for k in "rgba"},
            "required": list("rgba"),
        },
    },
}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
#: Foxglove's well-known pose schema (the fields graphpos writes).
POSE_IN_FRAME_SCHEMA = {
    "title": "foxglove.PoseInFrame",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
    },
}
#: Foxglove's well-known GeoJSON schema (the map of tags and RSUs).
GEOJSON_SCHEMA = {
    "title": "foxglove.GeoJSON",
    "type": "object",
    "properties": {"geojson": {"type": "string", "description": "GeoJSON data encoded as a string"}},
}


# ---------------------------------------------------------------------------
# Encoding
# ---------------------------------------------------------------------------


def _json_texts(values: list) -> list[bytes]:
    """The JSON text of each item of a list of Python floats and ints, from one msgspec encoding of the list."""
    if not values:
        return []
    import msgspec  # here, not at import: 40 ms of every command's start-up

    return msgspec.json.encode(values)[1:-1].split(b",")


def float_texts(values: np.ndarray, nan: bytes = b"null", inf: bytes = b"1e999", minus_inf: bytes = b"-1e999") -> list[bytes]:
    """ASCII texts of 1-D float64 values: Python's shortest round-trip repr
    (what ``float(text)`` reads back bit-exact), and the given texts for
    NaN, +inf and -inf (by default JSON's: null, and numbers that parse as
    +-inf).

    The whole column is encoded by msgspec in one call: its text of a float
    is repr's (the same shortest digits, laid out alike) for every magnitude
    in [1e-4, 1e16) or under 1e-9, zero included. Elsewhere it writes the
    exponent without a sign or a padding zero (``1e16``, ``1e-7`` for
    repr's ``1e+16``, ``1e-07``) or ``0.00001`` for ``1e-05``: those
    values take repr, and NaN and +-inf (msgspec's ``null``) the given
    texts.
    """
    arr = np.asarray(values, dtype=np.float64)
    texts = _json_texts(arr.tolist())
    magnitude = np.abs(arr)
    odd = np.flatnonzero(~(((magnitude >= 1e-4) & (magnitude < 1e16)) | (magnitude < 1e-9)))  # NaN compares False: odd
    if odd.size == 0:
        return texts
    texts = np.array(texts, dtype=object)
    value = arr[odd]
    finite = np.isfinite(value)
    if finite.any():
        texts[odd[finite]] = ",".join(map(float.__repr__, value[finite].tolist())).encode().split(b",")
    texts[odd[np.isnan(value)]] = nan
    texts[odd[value == np.inf]] = inf
    texts[odd[value == -np.inf]] = minus_inf
    return texts.tolist()


def _int_texts(values: np.ndarray) -> list[bytes]:
    """JSON integers of whole float64 values; the float texts when a value
    is not a whole number within the int64 range (the reader refuses it then,
    naming the row), so that nothing is rounded on the way."""
    arr = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        whole = np.isfinite(arr) & (arr == np.round(arr)) & (np.abs(arr) < 2.0**63)
    if not np.all(whole):
        return float_texts(arr)
    return _json_texts(arr.astype(np.int64).tolist())


def _json_template(fields: Sequence[tuple[str, str]]) -> bytes:
    """The ``%`` template of a JSON object from (name, value) per field: a
    value is JSON text, with ``%s`` where a column's text goes (no other
    ``%``)."""
    return ("{" + ",".join(f'"{name}":{value}' for name, value in fields) + "}").encode()


def _fill(template: bytes, columns: Sequence[list[bytes]]) -> list[bytes]:
    """One message per row: ``template`` with the row's text of each column in its ``%s`` slots, in order."""
    return list(map(template.__mod__, zip(*columns)))


def _time_ns(t_s: np.ndarray, base_s: float) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        ns = np.round((np.asarray(t_s, dtype=np.float64) - base_s) * 1e9)
    return np.clip(np.nan_to_num(ns, nan=0.0), 0.0, _MAX_UINT64_NS).astype(np.uint64)


def log_time_ns(t_s: float, time_base_s: float = 0.0) -> int:
    """The message log time of a row at ``t_s``: integer nanoseconds after
    ``time_base_s`` (the ``time_base_s`` of :func:`drive_metadata`), clipped
    to the uint64 range (0 for NaN)."""
    return int(_time_ns(np.array([t_s]), time_base_s)[0])


#: The value of a time stamp field in a template (:func:`_json_template`): a column of :func:`_stamps` in each slot.
_STAMP = '{"sec":%s,"nsec":%s}'


def _stamps(ns: np.ndarray) -> tuple[list[bytes], list[bytes]]:
    """The JSON texts of the whole seconds and the nanoseconds of time stamps in nanoseconds."""
    return _json_texts((ns // 1_000_000_000).tolist()), _json_texts((ns % 1_000_000_000).tolist())


def _thin(t_s: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indexes of the first sample of each 1/rate_hz bin."""
    if t_s.size == 0:
        return np.zeros(0, dtype=np.int64)
    with np.errstate(over="ignore", invalid="ignore"):
        bins = np.floor(np.asarray(t_s) * rate_hz)
    return np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])


def _location_fixes(t_ns: np.ndarray, east_m, north_m, var_m2: tuple[np.ndarray, np.ndarray] | None, origin: GeoOrigin,
                    colored_as: str | None = None) -> list[bytes]:
    """LocationFix messages; ``var_m2`` = (east, north) variances where known; ``colored_as``: the estimator
    (or ``truth``) whose colour (:func:`graphpos.colors.rgb_of`) the fixes carry, None for none."""
    from graphpos.io.geo import enu_to_geodetic

    lat, lon = enu_to_geodetic(east_m, north_m, origin)
    fields = [("timestamp", _STAMP), ("frame_id", f'"{POSE_FRAME}"'), ("latitude", "%s"), ("longitude", "%s"),
              ("altitude", repr(float(origin.alt_m)))]
    columns = [*_stamps(t_ns), float_texts(lat), float_texts(lon)]
    if var_m2 is None:
        fields += [("position_covariance", "[0,0,0,0,0,0,0,0,0]"), ("position_covariance_type", "0")]
    else:
        fields += [("position_covariance", "[%s,0,0,0,%s,0,0,0,0]"), ("position_covariance_type", "2")]
        columns += [float_texts(var_m2[0]), float_texts(var_m2[1])]
    if colored_as is not None:
        r, g, b = rgb_of(colored_as)
        fields.append(("color", json.dumps({"r": r, "g": g, "b": b, "a": 1.0})))
    return _fill(_json_template(fields), columns)


_POSE = _json_template([
    ("timestamp", _STAMP),
    ("frame_id", f'"{POSE_FRAME}"'),
    ("pose", '{"position":{"x":%s,"y":%s,"z":0.0},"orientation":{"x":0.0,"y":0.0,"z":%s,"w":%s}}'),
])


def _poses(t_ns: np.ndarray, east_m, north_m, yaw_rad) -> list[bytes]:
    yaw = np.nan_to_num(np.asarray(yaw_rad, dtype=np.float64)) if yaw_rad is not None else np.zeros(t_ns.size)
    return _fill(_POSE, [*_stamps(t_ns), float_texts(east_m), float_texts(north_m), float_texts(np.sin(yaw / 2)),
                         float_texts(np.cos(yaw / 2))])


def location_fix_payload(t_ns: int, east_m: float, north_m: float, var_en_m2: tuple[float, float] | None,
                         origin: GeoOrigin, name: str | None) -> bytes:
    """One ``foxglove.LocationFix`` message (:data:`LOCATION_FIX_SCHEMA`), as the viewing topics hold them.

    Parameters
    ----------
    t_ns : int
        Its time stamp (the message's log time).
    east_m, north_m : float
        Position in the drive's local frame.
    var_en_m2 : (float, float) or None
        East and north variances (a diagonal covariance), None where unknown.
    origin : GeoOrigin
        Geodetic origin of the local frame.
    name : str or None
        The estimator (or ``truth``) whose colour the fix carries
        (:func:`graphpos.colors.rgb_of`); None for none (GNSS, RSU fixes).
    """
    var = None if var_en_m2 is None else (np.array([var_en_m2[0]], dtype=np.float64), np.array([var_en_m2[1]], dtype=np.float64))
    return _location_fixes(np.array([t_ns], dtype=np.uint64), np.array([east_m], dtype=np.float64),
                           np.array([north_m], dtype=np.float64), var, origin, name)[0]


def pose_payload(t_ns: int, east_m: float, north_m: float, yaw_rad: float | None) -> bytes:
    """One ``foxglove.PoseInFrame`` message (:data:`POSE_IN_FRAME_SCHEMA`) in frame
    :data:`POSE_FRAME`, as the viewing topics hold them; a yaw of None or NaN
    is drawn as 0."""
    yaw = None if yaw_rad is None else np.array([yaw_rad], dtype=np.float64)
    return _poses(np.array([t_ns], dtype=np.uint64), np.array([east_m], dtype=np.float64),
                  np.array([north_m], dtype=np.float64), yaw)[0]


def map_geojson_payload(drive: Drive, origin: GeoOrigin) -> bytes:
    """The ``foxglove.GeoJSON`` message of the ``/map`` topic (:data:`GEOJSON_SCHEMA`):
    the drive's tags (with wall side, group, layouts) and RSUs as points about ``origin``."""
    from graphpos.io.geo import enu_to_geodetic

    features = []
    tags = drive.tags
    lat, lon = enu_to_geodetic(tags.east_m, tags.north_m, origin)
    member = {name: set(ids.tolist()) for name, ids in tags.layouts.items()}
    for i, tag_id in enumerate(tags.tag_id.tolist()):
        props = {
            "kind": "tag",
            "tag_id": tag_id,
            "wall_side": int(tags.wall_side[i]),
            "group": int(tags.group[i]),
            "layouts": [name for name, ids in member.items() if tag_id in ids],
        }
        features.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon[i], lat[i]]}, "properties": props})
    lat, lon = enu_to_geodetic(drive.rsus.east_m, drive.rsus.north_m, origin)
    for i, rsu_id in enumerate(drive.rsus.rsu_id.tolist()):
        features.append(
            {"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon[i], lat[i]]}, "properties": {"kind": "rsu", "rsu_id": rsu_id}}
        )
    geojson = json.dumps({"type": "FeatureCollection", "features": features})
    return json.dumps({"geojson": geojson}).encode()


def _jsonable(value: Any) -> Any:
    """json.dumps fallback: numpy scalars/arrays as Python values, tuples as lists."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def _dumps(value: Any, what: str) -> str:
    try:
        return json.dumps(value, default=_jsonable)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{what} cannot be stored in the file: {exc}") from None


def drive_metadata(drive: Drive, origin: GeoOrigin | None = None, time_base_s: float | None = None) -> dict[str, str]:
    """The ``graphpos.drive`` metadata record of a drive: format, name,
    origin, params, windows, tag and RSU maps, time base.

    Parameters
    ----------
    drive : Drive
        Its channels matter only for the default time base.
    origin : GeoOrigin, optional
        Defaults to ``drive.origin``.
    time_base_s : float, optional
        What the message log times count from (:func:`log_time_ns`):
        defaults to 0, or the whole second before the drive's start when it
        is negative.

    Raises
    ------
    ConfigError
        Params that are not JSON-serialisable.
    """
    origin = origin if origin is not None else drive.origin
    base_s = time_base_s if time_base_s is not None else _time_base_s(drive, ())
    tags, rsus = drive.tags, drive.rsus
    return {
        "format": f"{FORMAT_NAME}/{FORMAT_VERSION}",
        "name": drive.name,
        "origin": json.dumps({"lat_deg": float(origin.lat_deg), "lon_deg": float(origin.lon_deg), "alt_m": float(origin.alt_m)}),
        "params": _dumps(drive.params, "drive params"),
        "windows": json.dumps([{"label": w.label, "start_s": float(w.start_s), "end_s": float(w.end_s)} for w in drive.windows]),
        "tags": json.dumps(
            {
                "tag_id": tags.tag_id.tolist(),
                "east_m": tags.east_m.tolist(),
                "north_m": tags.north_m.tolist(),
                "wall_side": tags.wall_side.tolist(),
                "group": tags.group.tolist(),
                "layouts": {name: ids.tolist() for name, ids in tags.layouts.items()},
            }
        ),
        "rsus": json.dumps({"rsu_id": rsus.rsu_id.tolist(), "east_m": rsus.east_m.tolist(), "north_m": rsus.north_m.tolist()}),
        "time_base_s": repr(base_s),
    }


def _topic(name: str, schema: dict[str, Any], log_ns: np.ndarray, payloads: list[bytes], metadata: dict[str, str] | None = None) -> Topic:
    return Topic(name, schema["title"], json.dumps(schema).encode(), log_ns, payloads, metadata or {})


def _encode_columns(kind: str, columns: Mapping[str, np.ndarray]) -> list[bytes]:
    """One JSON message per row of the columns of channel ``kind`` (every
    column of its specs), fields in spec order."""
    specs = CHANNEL_SPECS[kind]
    template = _json_template([(spec.name, "%s") for spec in specs])
    return _fill(template, [(_int_texts if spec.integer else float_texts)(columns[spec.name]) for spec in specs])


def _encode_channel(ch: Channel) -> list[bytes]:
    """One JSON message per row, encoded in batches (the per-value texts
    of a whole hour-long channel would take hundreds of MB)."""
    payloads: list[bytes] = []
    for first in range(0, len(ch), _BATCH_ROWS):
        rows = slice(first, first + _BATCH_ROWS)
        payloads += _encode_columns(ch.kind, {name: column[rows] for name, column in ch.columns.items()})
    return payloads


def encode_row(kind: str, values: Mapping[str, float]) -> bytes:
    """One message of channel ``kind``: the JSON of one row, as
    :func:`write_drive` writes each row (fields in
    :data:`~graphpos.drive.CHANNEL_SPECS` order).

    Parameters
    ----------
    kind : str
        The channel.
    values : mapping of str to float
        Column name -> value, as :meth:`graphpos.drive.Drive.measurements`
        gives a row. A missing optional column is NaN (``null``), a missing
        ``arrival_s`` is ``t_s``, as in a :class:`~graphpos.drive.Channel`.
        Values are written as they are (a bad one is refused on reading).

    Raises
    ------
    DriveError
        An unknown channel or column, a missing required column.
    """
    specs = _specs_of(kind)
    unknown = set(values) - {spec.name for spec in specs}
    if unknown:
        raise DriveError(kind, None, f"unknown column(s) {sorted(unknown)}")
    columns = {}
    for spec in specs:
        if spec.name in values:
            value = values[spec.name]
        elif spec.required:
            raise DriveError(kind, None, f"missing required column '{spec.name}'")
        else:
            value = values["t_s"] if spec.name == "arrival_s" else np.nan
        columns[spec.name] = np.array([value], dtype=np.float64)
    return _encode_columns(kind, columns)[0]


def _drive_topics(drive: Drive, origin: GeoOrigin, base_s: float) -> list[Topic]:
    topics = []
    for kind, ch in drive.channels.items():
        t_ns = _time_ns(ch.t_s, base_s)
        topics.append(_topic(f"/{kind}", channel_schema(kind), t_ns, _encode_channel(ch)))
    if drive.has("truth"):
        truth = drive.truth
        keep = _thin(truth.t_s, VIEW_RATE_HZ)
        t_ns = _time_ns(truth.t_s[keep], base_s)
        e, n = truth.east_m[keep], truth.north_m[keep]
        topics.append(_topic("/truth/fix", LOCATION_FIX_SCHEMA, t_ns, _location_fixes(t_ns, e, n, None, origin, "truth")))
        topics.append(_topic("/truth/pose", POSE_IN_FRAME_SCHEMA, t_ns, _poses(t_ns, e, n, truth.yaw_rad[keep])))
    if drive.has("gnss"):
        g = drive.gnss
        t_ns = _time_ns(g.t_s, base_s)
        topics.append(_topic("/gnss/fix", LOCATION_FIX_SCHEMA, t_ns, _location_fixes(t_ns, g.east_m, g.north_m, (g.sigma_m**2, g.sigma_m**2), origin)))
    if drive.has("rsu"):
        r = drive.rsu
        fix = np.isfinite(r.east_m) & np.isfinite(r.north_m)
        if fix.any():
            t_ns = _time_ns(r.t_s[fix], base_s)
            var = r.sigma_m[fix] ** 2
            data = _location_fixes(t_ns, r.east_m[fix], r.north_m[fix], (var, var), origin)
            topics.append(_topic("/rsu/fix", LOCATION_FIX_SCHEMA, t_ns, data))
    if len(drive.tags) or len(drive.rsus):
        topics.append(_topic("/map", GEOJSON_SCHEMA, _time_ns(np.array([drive.start_s]), base_s), [map_geojson_payload(drive, origin)]))
    return topics


def _estimate_payloads(columns: Sequence[np.ndarray | None]) -> list[bytes]:
    """One JSON message per output epoch from the (N,) columns of
    :data:`_ESTIMATE_FIELDS` (None for a quantity not estimated), the last
    one the (N, 2, 2) covariances."""
    *vectors, cov_en_m2 = columns
    fields = [(name, "null" if arr is None else "%s") for name, arr in zip(_ESTIMATE_FIELDS, vectors)]
    texts = [float_texts(arr) for arr in vectors if arr is not None]
    if cov_en_m2 is None:
        fields.append(("cov_en_m2", "null"))
    else:
        flat = float_texts(np.asarray(cov_en_m2, dtype=np.float64).reshape(-1))
        fields.append(("cov_en_m2", "[%s,%s,%s,%s]"))
        texts += [flat[k::4] for k in range(4)]
    return _fill(_json_template(fields), texts)


def encode_estimate_row(row: OutputRow) -> bytes:
    """One message of an ``/estimates/<name>`` topic: the JSON of one output
    epoch, as :func:`write_drive` writes each epoch of an estimate (null
    where the row has None)."""
    columns = [None if getattr(row, name) is None else np.array([getattr(row, name)], dtype=np.float64)
               for name in _ESTIMATE_FIELDS[:-1]]
    cov = None if row.cov_en_m2 is None else np.asarray(row.cov_en_m2, dtype=np.float64).reshape(1, 2, 2)
    return _estimate_payloads([*columns, cov])[0]


def estimate_channel_metadata(name: str, fields: Iterable[str], rate_hz: float, wall_time_s: float = float("nan"),
                              diagnostics: dict[str, Any] | None = None) -> dict[str, str]:
    """The channel metadata of an ``/estimates/<name>`` topic.

    Parameters
    ----------
    name : str
        The estimator.
    fields : iterable of str
        The optional fields it estimates (of ``v_east_mps``, ``v_north_mps``,
        ``yaw_rad``, ``cov_en_m2``); the others read back as None.
    rate_hz : float
        Nominal output rate.
    wall_time_s : float
        Processing time (NaN: unknown, e.g. while running live).
    diagnostics : dict, optional
        JSON-serialisable counters and figures (none by default).

    Raises
    ------
    ConfigError
        An unknown field, diagnostics that are not JSON-serialisable.
    """
    fields = set(fields)
    unknown = fields - set(_OPTIONAL_ESTIMATE_FIELDS)
    if unknown:
        raise ConfigError(f"estimate '{name}': unknown optional field(s) {sorted(unknown)} "
                          f"(known: {', '.join(_OPTIONAL_ESTIMATE_FIELDS)})")
    return {
        "estimator": name,
        "fields": ",".join(f for f in _OPTIONAL_ESTIMATE_FIELDS if f in fields),
        "rate_hz": repr(float(rate_hz)),
        "wall_time_s": repr(float(wall_time_s)),
        "diagnostics": _dumps(diagnostics or {}, f"diagnostics of estimate '{name}'"),
    }


def _estimate_topics(estimates: Sequence[Estimate], origin: GeoOrigin, base_s: float) -> list[Topic]:
    topics = []
    seen: set[str] = set()
    for est in estimates:
        if not isinstance(est, Estimate):
            raise ConfigError(f"estimates must be Estimate objects, got {type(est).__name__}")
        if not est.name or est.name in seen:
            raise ConfigError(f"estimate name {est.name!r} is empty or used twice; each estimate needs its own name")
        seen.add(est.name)
        present = [f for f in _OPTIONAL_ESTIMATE_FIELDS if getattr(est, f) is not None]
        meta = estimate_channel_metadata(est.name, present, est.rate_hz, est.wall_time_s, est.diagnostics)
        t_ns = _time_ns(est.t_s, base_s)
        topic = f"/estimates/{est.name}"
        payloads = _estimate_payloads([getattr(est, name) for name in _ESTIMATE_FIELDS])
        topics.append(_topic(topic, estimate_schema(), t_ns, payloads, meta))
        keep = _thin(est.t_s, VIEW_RATE_HZ)
        t_ns = t_ns[keep]
        e, nn = est.east_m[keep], est.north_m[keep]
        var = (est.cov_en_m2[keep, 0, 0], est.cov_en_m2[keep, 1, 1]) if est.cov_en_m2 is not None else None
        yaw = est.yaw_rad[keep] if est.yaw_rad is not None else None
        topics.append(_topic(f"{topic}/fix", LOCATION_FIX_SCHEMA, t_ns, _location_fixes(t_ns, e, nn, var, origin, est.name)))
        topics.append(_topic(f"{topic}/pose", POSE_IN_FRAME_SCHEMA, t_ns, _poses(t_ns, e, nn, yaw)))
    return topics


def _time_base_s(drive: Drive, estimates: Sequence[Estimate]) -> float:
    """0, or the whole second before the earliest (finite) time when it is negative."""
    times = [drive.start_s] + [float(np.min(e.t_s[np.isfinite(e.t_s)])) for e in estimates if np.isfinite(e.t_s).any()]
    return max(-1e10, min(0.0, float(np.floor(min(times)))))


def write_drive(path: str | os.PathLike, drive: Drive, estimates: Iterable[Estimate] = (), origin: GeoOrigin | None = None) -> None:
    """Write a drive (and optionally estimates of it) to one MCAP file.

    The file is written to a temporary file in the same folder and renamed
    into place, so a failure leaves no partial output.

    Parameters
    ----------
    path : path-like
        Output file (conventionally ``*.mcap``); replaced if it exists.
    drive : Drive
    estimates : iterable of Estimate
        Written as ``/estimates/<name>`` topics (names must be unique).
    origin : GeoOrigin, optional
        Geodetic origin of the local frame; defaults to ``drive.origin``.
        It is stored in the file and places the track on Foxglove's map.

    Raises
    ------
    ConfigError
        Params or diagnostics that are not JSON-serialisable, duplicate
        estimate names.
    FileFormatError
        The file cannot be written (missing folder, no permission ...).
    """
    from graphpos.io.outputs import atomic_output  # here, as graphpos.io.geo (pymap3d): reading needs neither

    path = Path(path)
    estimates = list(estimates)
    origin = origin if origin is not None else drive.origin
    base_s = _time_base_s(drive, estimates)
    metadata = drive_metadata(drive, origin, base_s)
    topics = _drive_topics(drive, origin, base_s) + _estimate_topics(estimates, origin, base_s)
    with atomic_output(path) as stream:
        write_mcap(stream, f"graphpos {__version__}", {FORMAT_NAME: metadata}, topics)


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------

_SCAN_JSON = json.scanner.make_scanner(json.JSONDecoder())


def _decode_messages(payloads: list[bytes], where: str, first: int) -> list[dict]:
    """One JSON object per message payload (UTF-8 JSON text each); ``first``
    is the index of the first payload in its topic (for error messages)."""
    # msgspec's decoder on each payload: 6x faster than json's C scanner.
    # Whatever msgspec takes, json reads the same (the values bit for bit);
    # what it refuses (bad JSON, but also NaN and 1e999, which json reads as
    # NaN and inf, and lone surrogates) goes to json's scanner, then to
    # json.loads, which either accepts it or says what is wrong.
    import msgspec  # on first read, not at import: 40 ms of every command's start-up

    scan = _SCAN_JSON
    decode = msgspec.json.decode
    rows = []
    append = rows.append
    for i, payload in enumerate(payloads, start=first):
        try:
            row = decode(payload)
        except msgspec.DecodeError:
            try:
                text = payload.decode()
                row, end = scan(text, 0)
                if end != len(text):
                    raise ValueError
            except (StopIteration, ValueError, RecursionError):
                try:
                    row = json.loads(payload)
                except (ValueError, RecursionError) as exc:
                    raise FileFormatError(f"{where}, message {i}: not valid JSON ({exc})") from None
        if type(row) is not dict:
            raise FileFormatError(f"{where}, message {i}: expected a JSON object, got {type(row).__name__}")
        append(row)
    return rows


@functools.cache
def _row_decoder(names: tuple[str, ...]):
    """msgspec's JSON decoder of a message whose fields ``names`` are each a number or null (others ignored)."""
    import msgspec

    fields = [(name, int | float | None | msgspec.UnsetType, msgspec.UNSET) for name in names]
    return msgspec.json.Decoder(msgspec.defstruct("Row", fields, gc=False))  # numbers only: nothing for the GC to track


def _number_table(payloads: list[bytes], names: tuple[str, ...]) -> np.ndarray | None:
    """The fields ``names`` of messages as a (messages, fields) float64 table, NaN for null; None unless
    msgspec reads every message as an object with every one of the fields a number or null (then the
    values are json's, :func:`_decode_messages`), and the caller decodes the batch message by message."""
    import msgspec

    decode, astuple = _row_decoder(names).decode, msgspec.structs.astuple
    try:
        try:  # straight into the table, the fast way, unless a value is null
            table = np.fromiter(itertools.chain.from_iterable(map(astuple, map(decode, payloads))), np.float64,
                                count=len(payloads) * len(names))
        except TypeError:  # a null (None), which np.array reads as NaN, or an absent field (UNSET): decoded again
            table = np.array(list(map(astuple, map(decode, payloads))), dtype=np.float64)
    except (msgspec.DecodeError, TypeError, OverflowError):  # not JSON msgspec takes, a value not a number, an absent field
        return None
    return table.reshape(len(payloads), len(names))


def _decode_columns(payloads: list[bytes], names: Sequence[str], where: str) -> tuple[dict[str, np.ndarray], set[str]]:
    """Float64 columns of the named fields (NaN where a message lacks one),
    and the names present in at least one message.

    Messages are decoded a batch (:data:`_BATCH_ROWS`) at a time, so that
    only one batch of Python objects is alive at once: straight into a
    table where every message has every field as a number or null
    (:func:`_number_table`), else as dicts whose fields are then checked.

    Raises
    ------
    FileFormatError
        A message is not a JSON object.
    JsonRuleError
        A field holds a value that is not a number (or null), naming the
        message (row): :func:`graphpos.io.json_rules.number_column`.
    """
    parts: dict[str, list[np.ndarray]] = {name: [] for name in names}
    present: set[str] = set()
    for first in range(0, len(payloads), _BATCH_ROWS):
        batch = payloads[first : first + _BATCH_ROWS]
        table = _number_table(batch, tuple(names)) if "cov_en_m2" not in names else None
        if table is not None:
            present.update(names)
            for i, name in enumerate(names):
                parts[name].append(table[:, i])
            continue
        rows = _decode_messages(batch, where, first)
        for name in names:
            if name not in present and any(name in row for row in rows):
                present.add(name)
            values = [row.get(name) for row in rows]
            parts[name].append(number_rows(values, name, first, 4) if name == "cov_en_m2" else number_column(values, name, first))
    empty = {"cov_en_m2": np.zeros((0, 4))}
    return {name: np.concatenate(parts[name]) if parts[name] else empty.get(name, np.zeros(0)) for name in names}, present


def _decode_channel(kind: str, payloads: list[bytes], where: str, arrival_order: bool) -> Channel:
    """The channel of a topic's messages; ``arrival_order``: the writer may
    have written rows in arrival order (:func:`_arrival_ordered`)."""
    specs = CHANNEL_SPECS[kind]
    try:
        decoded, present = _decode_columns(payloads, [s.name for s in specs], where)
    except JsonRuleError as exc:
        raise DriveError(kind, exc.row, f"field '{exc.field}' {exc.reason}") from None
    columns = {}
    for spec in specs:
        if not spec.required and spec.name not in present:
            continue  # a field no message has takes the channel's default (NaN; t_s for arrival_s)
        arr = decoded[spec.name]
        if spec.required:
            missing = np.isnan(arr)
            if missing.any():
                raise DriveError(kind, int(np.argmax(missing)), f"field '{spec.name}' is missing, null or NaN")
        columns[spec.name] = arr
    order = _arrival_ordered(columns) if arrival_order else None
    if order is None:
        return Channel(kind, columns)
    try:
        return Channel(kind, {name: arr[order] for name, arr in columns.items()})
    except DriveError as exc:  # name the row as the file holds it
        raise DriveError(kind, None if exc.row is None else int(order[exc.row]), exc.reason) from None


def _arrival_ordered(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    """The stable ``t_s`` order of rows recorded in arrival order: ``t_s``
    goes back somewhere and ``arrival_s`` (given) never does; None for rows
    to be taken in file order."""
    t_s, arrival_s = columns["t_s"], columns.get("arrival_s")
    if arrival_s is None or not (np.diff(t_s) < 0).any() or not (np.diff(arrival_s) >= 0).all():
        return None
    return np.argsort(t_s, kind="stable")


def _graphpos_channels(contents: McapContents, path: Path, schema_names: set[str]) -> list[tuple[str, McapChannel]]:
    """(schema name, channel) of the channels carrying one of ``schema_names``."""
    found = []
    for cid in sorted(contents.channels):
        channel = contents.channels[cid]
        schema = contents.schemas.get(channel.schema_id)
        if schema is None or schema.name not in schema_names:
            continue
        if channel.message_encoding != "json":
            raise FileFormatError(
                f"{path}: topic {channel.topic} ({schema.name}) has message encoding {channel.message_encoding!r}; graphpos reads 'json'"
            )
        found.append((schema.name, channel))
    return found


def _metadata_values(meta: dict[str, str], rules: dict[str, Rule], where: str) -> dict[str, Any]:
    """The JSON values of the keys of ``rules`` that the metadata ``meta``
    holds, each checked against its rule (other keys are ignored).

    Raises
    ------
    FileFormatError
        ``where`` (the file and the record), the key or field, and what is
        wrong with its value.
    """
    values = {}
    for key, rule in rules.items():
        if key not in meta:
            continue
        try:
            value = json.loads(meta[key])
        except (ValueError, RecursionError) as exc:
            raise FileFormatError(f"{where} '{key}' is not valid JSON ({exc})") from None
        try:
            check_value(value, rule, key)
        except JsonRuleError as exc:
            raise FileFormatError(f"{where} '{exc.field}' {exc.reason}") from None
        values[key] = value
    return values


def _drive_from(contents: McapContents, path: Path) -> Drive:
    meta = contents.metadata.get(FORMAT_NAME)
    found = _graphpos_channels(contents, path, set(_KIND_BY_SCHEMA))
    if meta is None and not found:
        topics = sorted({c.topic for c in contents.channels.values()})
        shown = ", ".join(topics[:6]) + (" ..." if len(topics) > 6 else "")
        raise FileFormatError(
            f"{path}: not a graphpos drive (no '{FORMAT_NAME}' metadata and no graphpos.* channels; topics: {shown or 'none'})"
        )
    meta = meta or {}
    fmt = meta.get("format", f"{FORMAT_NAME}/{FORMAT_VERSION}")
    name_part, _, version = fmt.partition("/")
    if name_part != FORMAT_NAME or not version.isdigit() or int(version) > FORMAT_VERSION:
        raise FileFormatError(f"{path}: unsupported drive format {fmt!r} (this graphpos reads {FORMAT_NAME}/{FORMAT_VERSION})")
    channels = {}
    arrival_order = contents.library.startswith(LIVE_LIBRARY)
    for schema_name, channel in found:
        kind = _KIND_BY_SCHEMA[schema_name]
        if kind in channels:
            raise FileFormatError(f"{path}: two topics carry the '{kind}' channel (schema {schema_name})")
        where = f"{path}: topic {channel.topic}"
        try:
            channels[kind] = _decode_channel(kind, contents.payloads.pop(channel.id, []), where, arrival_order)
        except DriveError as exc:
            raise exc.with_source(str(path)) from None
    values = _metadata_values(meta, DRIVE_METADATA_RULES, f"{path}: metadata")
    try:
        origin = GeoOrigin(**values.get("origin", {}))
        tags = TagMap(**values["tags"]) if "tags" in values else TagMap.empty()
        rsus = RsuMap(**values["rsus"]) if "rsus" in values else RsuMap.empty()
        windows = tuple(Window(**w) for w in values.get("windows", []))
    except DriveError as exc:  # a value out of its bounds (graphpos.drive): the file's metadata is at fault
        row = f", row {exc.row}" if exc.row is not None else ""
        raise FileFormatError(f"{path}: metadata '{exc.channel}'{row}: {exc.reason}") from None
    params = values.get("params", {})
    if contents.unclosed:
        params = {**params, "unclosed_recording": True}
    try:
        return Drive(name=meta.get("name", path.stem), channels=channels, tags=tags, rsus=rsus, windows=windows,
                     origin=origin, params=params)
    except DriveError as exc:
        raise exc.with_source(str(path)) from None


def read_drive(path: str | os.PathLike) -> Drive:
    """Read the drive of an MCAP file written by :func:`write_drive` or any
    tool that writes the same schemas.

    The drive of a recording ``graphpos live`` did not close (stopped,
    killed) holds the rows up to its last complete chunk, and its params
    ``"unclosed_recording": True``
    (:func:`graphpos.io.mcap_container.read_mcap_contents`).

    Raises
    ------
    FileFormatError
        Missing, empty, truncated, corrupt or foreign file (the message names
        the file, and the topic and message where known).
    DriveError
        The content fails drive validation (names the file, channel and row).
    """
    path = Path(path)
    return _drive_from(read_mcap_contents(path), path)


def _estimate_from(channel: McapChannel, payloads: list[bytes], path: Path) -> Estimate:
    where = f"{path}: topic {channel.topic}"
    meta = channel.metadata
    name = meta.get("estimator") or channel.topic.rsplit("/", 1)[-1]
    present = set(filter(None, meta.get("fields", ",".join(_OPTIONAL_ESTIMATE_FIELDS)).split(",")))
    try:
        decoded, _ = _decode_columns(payloads, _ESTIMATE_FIELDS, where)
    except JsonRuleError as exc:
        raise FileFormatError(f"{where}, message {exc.row}: field '{exc.field}' {exc.reason}") from None
    cols: dict[str, Any] = {
        field: decoded[field] if field in ("t_s", "east_m", "north_m") or field in present else None for field in _ESTIMATE_FIELDS
    }
    if cols["cov_en_m2"] is not None:
        cols["cov_en_m2"] = cols["cov_en_m2"].reshape(-1, 2, 2)
    diagnostics = _metadata_values(meta, ESTIMATE_METADATA_RULES, f"{where}: channel metadata").get("diagnostics", {})
    try:
        rate_hz = float(meta.get("rate_hz", "nan"))
        wall_time_s = float(meta.get("wall_time_s", "nan"))
    except ValueError as exc:
        raise FileFormatError(f"{where}: malformed channel metadata ({exc})") from None
    return Estimate(name=name, rate_hz=rate_hz, wall_time_s=wall_time_s, diagnostics=diagnostics, **cols)


def _estimates_from(contents: McapContents, path: Path) -> list[Estimate]:
    return [
        _estimate_from(channel, contents.payloads.get(channel.id, []), path)
        for _, channel in _graphpos_channels(contents, path, {_ESTIMATE_SCHEMA})
    ]


def read_estimates(path: str | os.PathLike) -> list[Estimate]:
    """The estimates stored in an MCAP file (empty list if it holds none).

    Raises
    ------
    FileFormatError
        As :func:`read_drive`.
    """
    path = Path(path)
    return _estimates_from(read_mcap_contents(path), path)


def read_mcap(path: str | os.PathLike) -> tuple[Drive, list[Estimate]]:
    """The drive and the estimates of an MCAP file, reading it once.

    Raises
    ------
    FileFormatError, DriveError
        As :func:`read_drive`.
    """
    path = Path(path)
    contents = read_mcap_contents(path)
    return _drive_from(contents, path), _estimates_from(contents, path)
