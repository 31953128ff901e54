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
number belongs: never coerced, :mod:`graphpos.io.json_rules`).

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
channel's rows keep the order of its messages in the file.
"""

from __future__ import annotations

import json
import json.scanner
import os
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np
from mcap.records import Channel as McapChannel

from graphpos import __version__
from graphpos.colors import rgb_of
from graphpos.drive import CHANNEL_SPECS, Channel, Drive, GeoOrigin, RsuMap, TagMap, Window
from graphpos.errors import ConfigError, DriveError, FileFormatError
from graphpos.estimate import Estimate
from graphpos.io.outputs import atomic_output
from graphpos.io.geo import enu_to_geodetic
from graphpos.io.json_rules import (DRIVE_METADATA_RULES, ESTIMATE_METADATA_RULES, JsonRuleError, Rule, check_value,
                                    number_column, number_rows)
from graphpos.io.mcap_container import McapContents, Topic, read_mcap_contents, write_mcap

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


# ---------------------------------------------------------------------------
# JSON schemas
# ---------------------------------------------------------------------------


def _channel_schema(kind: str) -> dict[str, Any]:
    props = {}
    for spec in CHANNEL_SPECS[kind]:
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
        "required": [s.name for s in CHANNEL_SPECS[kind] if s.required],
    }


def _estimate_schema() -> dict[str, Any]:
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
_LOCATION_FIX_SCHEMA = {
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
_POSE_IN_FRAME_SCHEMA = {
    "title": "foxglove.PoseInFrame",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
    },
}
_GEOJSON_SCHEMA = {
    "title": "foxglove.GeoJSON",
    "type": "object",
    "properties": {"geojson": {"type": "string", "description": "GeoJSON data encoded as a string"}},
}


# ---------------------------------------------------------------------------
# Encoding
# ---------------------------------------------------------------------------


def _float_texts(values: np.ndarray) -> list[str]:
    """JSON texts of float64 values: shortest round-trip repr, null for NaN."""
    arr = np.asarray(values, dtype=np.float64)
    texts = list(map(float.__repr__, arr.tolist()))
    bad = np.flatnonzero(~np.isfinite(arr))
    for i in bad.tolist():
        v = arr[i]
        texts[i] = "null" if np.isnan(v) else ("1e999" if v > 0 else "-1e999")
    return texts


def _int_texts(values: np.ndarray) -> list[str]:
    arr = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        return _float_texts(arr)
    return list(map(str, arr.astype(np.int64).tolist()))


def _encode_rows(names: Sequence[str], texts: Sequence[list[str]]) -> list[bytes]:
    """One JSON object per row from per-column value texts."""
    template = "{" + ",".join(f'"{name}":%s' for name in names) + "}"
    fill = template.__mod__
    return [s.encode() for s in map(fill, zip(*texts))]


def _time_ns(t_s: np.ndarray, base_s: float) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        ns = np.round((np.asarray(t_s, dtype=np.float64) - base_s) * 1e9)
    return np.clip(np.nan_to_num(ns, nan=0.0), 0.0, _MAX_UINT64_NS).astype(np.uint64)


def _stamps(ns: np.ndarray) -> tuple[list[str], list[str]]:
    return list(map(str, (ns // 1_000_000_000).tolist())), list(map(str, (ns % 1_000_000_000).tolist()))


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
    lat, lon = enu_to_geodetic(east_m, north_m, origin)
    sec, nsec = _stamps(t_ns)
    n = t_ns.size
    if var_m2 is None:
        cov = ["[0,0,0,0,0,0,0,0,0]"] * n
        cov_type = ["0"] * n
    else:
        cov = [f"[{e},0,0,0,{nn},0,0,0,0]" for e, nn in zip(_float_texts(var_m2[0]), _float_texts(var_m2[1]))]
        cov_type = ["2"] * n
    names = ["timestamp", "frame_id", "latitude", "longitude", "altitude", "position_covariance", "position_covariance_type"]
    stamp = [f'{{"sec":{s},"nsec":{ns}}}' for s, ns in zip(sec, nsec)]
    texts = [stamp, [f'"{POSE_FRAME}"'] * n, _float_texts(lat), _float_texts(lon), [repr(float(origin.alt_m))] * n, cov, cov_type]
    if colored_as is not None:
        r, g, b = rgb_of(colored_as)
        names.append("color")
        texts.append([json.dumps({"r": r, "g": g, "b": b, "a": 1.0})] * n)
    return _encode_rows(names, texts)


def _poses(t_ns: np.ndarray, east_m, north_m, yaw_rad) -> list[bytes]:
    sec, nsec = _stamps(t_ns)
    yaw = np.nan_to_num(np.asarray(yaw_rad, dtype=np.float64)) if yaw_rad is not None else np.zeros(t_ns.size)
    qz, qw = _float_texts(np.sin(yaw / 2)), _float_texts(np.cos(yaw / 2))
    e, n = _float_texts(east_m), _float_texts(north_m)
    return [
        (
            f'{{"timestamp":{{"sec":{s},"nsec":{ns}}},"frame_id":"{POSE_FRAME}","pose":{{"position":{{"x":{x},"y":{y},"z":0.0}},'
            f'"orientation":{{"x":0.0,"y":0.0,"z":{z},"w":{w}}}}}}}'
        ).encode()
        for s, ns, x, y, z, w in zip(sec, nsec, e, n, qz, qw)
    ]


def _map_geojson(drive: Drive, origin: GeoOrigin) -> bytes:
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


def _drive_metadata(drive: Drive, origin: GeoOrigin, base_s: float) -> dict[str, str]:
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


def _encode_channel(ch: Channel) -> list[bytes]:
    """One JSON message per row, encoded in batches (the per-value texts
    of a whole hour-long channel would take hundreds of MB)."""
    names = [spec.name for spec in ch.specs]
    payloads: list[bytes] = []
    for first in range(0, len(ch), _BATCH_ROWS):
        rows = slice(first, first + _BATCH_ROWS)
        texts = [(_int_texts if spec.integer else _float_texts)(ch[spec.name][rows]) for spec in ch.specs]
        payloads += _encode_rows(names, texts)
    return payloads


def _drive_topics(drive: Drive, origin: GeoOrigin, base_s: float) -> list[Topic]:
    topics = []
    for kind, ch in drive.channels.items():
        t_ns = _time_ns(ch.t_s, base_s)
        topics.append(_topic(f"/{kind}", _channel_schema(kind), t_ns, _encode_channel(ch)))
    if drive.has("truth"):
        truth = drive.truth
        keep = _thin(truth.t_s, VIEW_RATE_HZ)
        t_ns = _time_ns(truth.t_s[keep], base_s)
        e, n = truth.east_m[keep], truth.north_m[keep]
        topics.append(_topic("/truth/fix", _LOCATION_FIX_SCHEMA, t_ns, _location_fixes(t_ns, e, n, None, origin, "truth")))
        topics.append(_topic("/truth/pose", _POSE_IN_FRAME_SCHEMA, t_ns, _poses(t_ns, e, n, truth.yaw_rad[keep])))
    if drive.has("gnss"):
        g = drive.gnss
        t_ns = _time_ns(g.t_s, base_s)
        topics.append(_topic("/gnss/fix", _LOCATION_FIX_SCHEMA, t_ns, _location_fixes(t_ns, g.east_m, g.north_m, (g.sigma_m**2, g.sigma_m**2), origin)))
    if drive.has("rsu"):
        r = drive.rsu
        fix = np.isfinite(r.east_m) & np.isfinite(r.north_m)
        if fix.any():
            t_ns = _time_ns(r.t_s[fix], base_s)
            var = r.sigma_m[fix] ** 2
            data = _location_fixes(t_ns, r.east_m[fix], r.north_m[fix], (var, var), origin)
            topics.append(_topic("/rsu/fix", _LOCATION_FIX_SCHEMA, t_ns, data))
    if len(drive.tags) or len(drive.rsus):
        topics.append(_topic("/map", _GEOJSON_SCHEMA, _time_ns(np.array([drive.start_s]), base_s), [_map_geojson(drive, origin)]))
    return topics


def _estimate_topics(estimates: Sequence[Estimate], origin: GeoOrigin, base_s: float) -> list[Topic]:
    topics = []
    seen: set[str] = set()
    for est in estimates:
        if not isinstance(est, Estimate):
            raise ConfigError(f"estimates must be Estimate objects, got {type(est).__name__}")
        if not est.name or est.name in seen:
            raise ConfigError(f"estimate name {est.name!r} is empty or used twice; each estimate needs its own name")
        seen.add(est.name)
        n = len(est)
        present = [f for f in _OPTIONAL_ESTIMATE_FIELDS if getattr(est, f) is not None]
        texts = []
        for name in _ESTIMATE_FIELDS[:-1]:
            arr = getattr(est, name)
            texts.append(_float_texts(arr) if arr is not None else ["null"] * n)
        if est.cov_en_m2 is not None:
            flat = _float_texts(est.cov_en_m2.reshape(-1))
            texts.append(["[" + ",".join(flat[4 * i : 4 * i + 4]) + "]" for i in range(n)])
        else:
            texts.append(["null"] * n)
        t_ns = _time_ns(est.t_s, base_s)
        meta = {
            "estimator": est.name,
            "fields": ",".join(present),
            "rate_hz": repr(float(est.rate_hz)),
            "wall_time_s": repr(float(est.wall_time_s)),
            "diagnostics": _dumps(est.diagnostics, f"diagnostics of estimate '{est.name}'"),
        }
        topic = f"/estimates/{est.name}"
        topics.append(_topic(topic, _estimate_schema(), t_ns, _encode_rows(_ESTIMATE_FIELDS, texts), meta))
        keep = _thin(est.t_s, VIEW_RATE_HZ)
        t_ns = t_ns[keep]
        e, nn = est.east_m[keep], est.north_m[keep]
        var = (est.cov_en_m2[keep, 0, 0], est.cov_en_m2[keep, 1, 1]) if est.cov_en_m2 is not None else None
        yaw = est.yaw_rad[keep] if est.yaw_rad is not None else None
        topics.append(_topic(f"{topic}/fix", _LOCATION_FIX_SCHEMA, t_ns, _location_fixes(t_ns, e, nn, var, origin, est.name)))
        topics.append(_topic(f"{topic}/pose", _POSE_IN_FRAME_SCHEMA, t_ns, _poses(t_ns, e, nn, yaw)))
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
    path = Path(path)
    estimates = list(estimates)
    origin = origin if origin is not None else drive.origin
    base_s = _time_base_s(drive, estimates)
    metadata = _drive_metadata(drive, origin, base_s)
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
    # json's C scanner on each payload: 3x faster than json.loads, whose
    # Python-level checks dominate on small messages. Anything it does not
    # take whole (whitespace around the value, bad JSON) goes to json.loads,
    # which either accepts it or says what is wrong.
    scan = _SCAN_JSON
    rows = []
    append = rows.append
    for i, payload in enumerate(payloads, start=first):
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


def _batches(payloads: list[bytes], where: str) -> Iterator[tuple[int, list[dict]]]:
    """(index of the first message, decoded messages) in batches, so that
    only one batch of Python dicts is alive at a time."""
    for first in range(0, len(payloads), _BATCH_ROWS):
        yield first, _decode_messages(payloads[first : first + _BATCH_ROWS], where, first)


def _decode_columns(payloads: list[bytes], names: Sequence[str], where: str) -> tuple[dict[str, np.ndarray], set[str]]:
    """Float64 columns of the named fields (NaN where a message lacks one),
    and the names present in at least one message.

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
    for first, rows in _batches(payloads, where):
        for name in names:
            if name not in present and any(name in row for row in rows):
                present.add(name)
            values = [row.get(name) for row in rows]
            parts[name].append(number_rows(values, name, first, 4) if name == "cov_en_m2" else number_column(values, name, first))
    empty = {"cov_en_m2": np.zeros((0, 4))}
    return {name: np.concatenate(parts[name]) if parts[name] else empty.get(name, np.zeros(0)) for name in names}, present


def _decode_channel(kind: str, payloads: list[bytes], where: str) -> Channel:
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
    return Channel(kind, columns)


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
    for schema_name, channel in found:
        kind = _KIND_BY_SCHEMA[schema_name]
        if kind in channels:
            raise FileFormatError(f"{path}: two topics carry the '{kind}' channel (schema {schema_name})")
        where = f"{path}: topic {channel.topic}"
        try:
            channels[kind] = _decode_channel(kind, contents.payloads.pop(channel.id, []), where)
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
    try:
        return Drive(name=meta.get("name", path.stem), channels=channels, tags=tags, rsus=rsus, windows=windows,
                     origin=origin, params=values.get("params", {}))
    except DriveError as exc:
        raise exc.with_source(str(path)) from None


def read_drive(path: str | os.PathLike) -> Drive:
    """Read the drive of an MCAP file written by :func:`write_drive` or any
    tool that writes the same schemas.

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
