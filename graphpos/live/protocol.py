"""The live wire format: one JSON object per UDP datagram or per TCP line.

A measurement is a row of one of the drive's channels, with the channel's
own columns (:data:`graphpos.drive.CHANNEL_SPECS`, units in the names)::

    {"channel": "imu", "seq": 17, "t_s": 12.34, "yaw_rate_radps": 0.012, "accel_x_mps2": 0.3, "accel_y_mps2": -0.1}
    {"channel": "rfid", "seq": 18, "t_s": 12.30, "arrival_s": 12.35, "tag_id": 7, "rss": 181.0, "range_m": null}

- ``channel``: ``imu``, ``wheel``, ``compass``, ``rfid``, ``rsu`` or
  ``gnss``. Truth is for scoring only and is never taken live.
- The channel's required columns are JSON numbers (ids whole numbers),
  finite and within the columns' plausible bounds, as in a drive file
  (:mod:`graphpos.io.json_rules`: nothing is coerced, ``"2.0"`` is not a
  number); optional ones may be ``null`` or absent. Unknown fields are
  ignored, as a drive file's are.
- ``arrival_s`` (rfid, rsu; optional): when the reading reached the
  sender's computer, on the clock of ``t_s``; a reading is never taken to
  have arrived before anything already received (see
  :class:`graphpos.live.session.LiveSession`).
- ``seq`` (optional): the sender's message counter (a whole number, one
  per message, increasing). With it live mode drops duplicates and counts
  lost and reordered messages; without it duplicates are recognised by
  their identical bytes.

``{"channel": "end", "seq": N}`` ends the drive: the estimators finish,
the recording is closed and ``graphpos live`` exits.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from graphpos.drive import CHANNEL_SPECS, Drive, Measurement
from graphpos.live.malformed import MalformedMessage

#: Channels a live feed may carry (truth is for scoring only).
LIVE_CHANNELS: tuple[str, ...] = tuple(c for c in CHANNEL_SPECS if c != "truth")
#: The channel name of the end-of-drive message.
END = "end"
#: Largest message accepted (a UDP datagram holds at most 65507 bytes).
MAX_MESSAGE_BYTES = 65536
_NUMBER = (int, float)
#: The integer (id) columns of each channel, written as JSON integers.
_INTEGER_COLUMNS = {c: frozenset(spec.name for spec in CHANNEL_SPECS[c] if spec.integer) for c in LIVE_CHANNELS}


@dataclass(frozen=True)
class Received:
    """One decoded message: a measurement, or the end of the drive (``measurement`` None)."""

    measurement: Measurement | None
    seq: int | None


def _no_constants(name: str) -> float:
    raise ValueError(f"{name} is not JSON")


def encode(m: Measurement, seq: int | None = None) -> bytes:
    """The message of one measurement (NaN as null; floats in shortest round-trip form, so they decode bit-exact)."""
    body: dict[str, Any] = {"channel": m.channel}
    if seq is not None:
        body["seq"] = seq
    for name, value in m.values.items():
        if name == "arrival_s" and value == m.t_s:
            continue
        body[name] = None if value != value else (int(value) if name in _INTEGER_COLUMNS[m.channel] else float(value))
    return json.dumps(body, separators=(",", ":"), allow_nan=False).encode()


def encode_end(seq: int | None = None) -> bytes:
    """The end-of-drive message."""
    return json.dumps({"channel": END, **({"seq": seq} if seq is not None else {})}).encode()


class Decoder:
    """Checks and decodes messages against a site's maps.

    Parameters
    ----------
    site : Drive
        The tag and RSU maps readings may name.
    """

    def __init__(self, site: Drive):
        self._tags = {int(t) for t in site.tags.tag_id}
        self._rsus = {int(r) for r in site.rsus.rsu_id}
        self._columns = {c: CHANNEL_SPECS[c] for c in LIVE_CHANNELS}

    def decode(self, payload: bytes) -> Received:
        """The message in ``payload``.

        Raises
        ------
        MalformedMessage
            Not a JSON object, an unknown channel, a missing, mistyped or
            out-of-range field, an unknown tag or RSU id (one line saying which).
        """
        if len(payload) > MAX_MESSAGE_BYTES:
            raise MalformedMessage("size", f"message of {len(payload)} bytes (at most {MAX_MESSAGE_BYTES})")
        try:
            body = json.loads(payload, parse_constant=_no_constants)
        except (ValueError, RecursionError) as exc:
            raise MalformedMessage("json", f"not JSON ({str(exc)[:80]})") from None
        if type(body) is not dict:
            raise MalformedMessage("json", f"not a JSON object but {type(body).__name__}")
        seq = body.get("seq")
        if seq is not None and (type(seq) is not int or seq < 0):
            raise MalformedMessage("field", f"seq {str(seq)[:30]!r} is not a whole number >= 0")
        try:
            return self._decode_body(body, seq)
        except MalformedMessage as exc:
            exc.seq = seq
            raise

    def _decode_body(self, body: dict[str, Any], seq: int | None) -> Received:
        channel = body.get("channel")
        if channel == END:
            return Received(None, seq)
        if channel not in self._columns:
            known = ", ".join(LIVE_CHANNELS)
            if channel == "truth":
                raise MalformedMessage("channel", "truth is for scoring only; live mode does not take it")
            raise MalformedMessage("channel", f"unknown channel {str(channel)[:40]!r} (known: {known}, {END})")
        values: dict[str, float] = {}
        for spec in self._columns[channel]:
            value = body.get(spec.name)
            if value is None:
                if spec.required:
                    raise MalformedMessage("field", f"{channel}: field '{spec.name}' is missing or null")
                values[spec.name] = math.nan
                continue
            if type(value) not in _NUMBER:
                raise MalformedMessage("field", f"{channel}: field '{spec.name}' is {str(value)[:30]!r}, not a number")
            x = float(value)
            if not math.isfinite(x) or not spec.lo <= x <= spec.hi:
                raise MalformedMessage("field", f"{channel}: {spec.name} = {x:.6g} is outside [{spec.lo:g}, {spec.hi:g}]")
            if spec.integer and x != int(x):
                raise MalformedMessage("field", f"{channel}: {spec.name} = {x!r} is not a whole number")
            values[spec.name] = x
        t_s = values["t_s"]
        if "arrival_s" in values:
            if values["arrival_s"] != values["arrival_s"]:
                values["arrival_s"] = t_s
            elif values["arrival_s"] < t_s:
                raise MalformedMessage("field", f"{channel}: arrival_s {values['arrival_s']!r} is before t_s {t_s!r}")
        if channel == "rfid" and int(values["tag_id"]) not in self._tags:
            raise MalformedMessage("id", f"rfid: tag id {int(values['tag_id'])} is not in the site's tag map")
        if channel == "rsu":
            if int(values["rsu_id"]) not in self._rsus:
                raise MalformedMessage("id", f"rsu: RSU id {int(values['rsu_id'])} is not in the site's RSU map")
            fix = math.isfinite(values["east_m"]) and math.isfinite(values["north_m"])
            if not fix and not math.isfinite(values["range_m"]):
                raise MalformedMessage("field", "rsu: a reading needs a position fix (east_m, north_m) or a range_m")
        return Received(Measurement(channel, t_s, values.get("arrival_s", t_s), values), seq)
