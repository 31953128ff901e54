"""The recording of a live session: one MCAP file that is a drive with its estimates, readable after any stop.

Written by :class:`graphpos.io.mcap_recorder.McapRecorder` (chunks of at
most about a second, each on disk once written, so that a ``kill -9``
loses at most the last second; SIGINT and SIGTERM close the file whole).
The file is a graphpos drive (:mod:`graphpos.io.mcap_drive`): the site's
maps and origin in the ``graphpos.drive`` metadata, every accepted
measurement on its channel's topic (``/imu``, ``/rfid`` ..., in the order
it arrived, with the arrival time it was given), and each estimator's
published rows on ``/estimates/NAME`` (with ``/fix`` and ``/pose`` for
Foxglove), so that ``graphpos run``, ``info`` and ``evaluate`` take it as
any drive, and :func:`graphpos.io.read_estimates` gives the causal
outputs exactly as they were published. Besides:

- ``/live/NAME/latency``: per measurement and estimator, ``t_s``,
  ``channel``, ``seq``, ``latency_ms`` (receipt to publish) and
  ``outputs`` (rows it completed);
- ``/live/status``: the session's status once a second (counts, lag, latency);
- ``/live/rejected``: each malformed message, raw (up to 1 KiB), with its
  reason, kind and source;
- metadata ``graphpos.live``: when, from which site, which estimators.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

from graphpos.drive import Drive, Measurement
from graphpos.estimate import OutputRow

_OPTIONAL_FIELDS = ("v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2")
_LATENCY_SCHEMA = {
    "title": "graphpos.live_latency",
    "type": "object",
    "properties": {"t_s": {"type": "number"}, "channel": {"type": "string"}, "seq": {"type": ["integer", "null"]},
                   "latency_ms": {"type": "number"}, "outputs": {"type": "integer"}},
}
_STATUS_SCHEMA = {"title": "graphpos.live_status", "type": "object"}
_REJECTED_SCHEMA = {
    "title": "graphpos.live_rejected",
    "type": "object",
    "properties": {"reason": {"type": "string"}, "kind": {"type": "string"}, "source": {"type": "string"},
                   "payload": {"type": "string", "description": "the message as received (up to 1 KiB, undecodable bytes escaped)"}},
}
_MAX_RAW_BYTES = 1024


class LiveRecording:
    """Records one live session into ``path``.

    Parameters
    ----------
    path : Path
        The MCAP file (written in place as it goes; see the module docstring).
    site : Drive
        Its maps and origin go into the file's drive metadata.
    live : dict
        JSON-serialisable description of the session (``graphpos.live`` metadata).
    """

    def __init__(self, path: Path, site: Drive, live: dict[str, Any]):
        from graphpos.io import mcap_drive as md
        from graphpos.io.mcap_recorder import McapRecorder

        self._md = md
        self._origin = site.origin
        self._recorder = McapRecorder(path)
        self._lock = threading.Lock()
        base = site.replace(channels={}, windows=(), params={**site.params, "live": live})
        meta = md.drive_metadata(base)
        self._base_s = float(meta.get("time_base_s", "0") or 0.0)
        self._recorder.add_metadata(md.FORMAT_NAME, meta)
        self._recorder.add_metadata("graphpos.live", {k: json.dumps(v) for k, v in live.items()})
        self._inputs: dict[str, int] = {}
        self._estimates: dict[str, tuple[int, int, int]] = {}
        self._latency: dict[str, int] = {}
        self._status = self._recorder.add_channel("/live/status", _STATUS_SCHEMA)
        self._rejected = self._recorder.add_channel("/live/rejected", _REJECTED_SCHEMA)
        map_channel = self._recorder.add_channel("/map", md.GEOJSON_SCHEMA)
        self._recorder.write(map_channel, 0, md.map_geojson_payload(site, site.origin))

    def _ns(self, t_s: float) -> int:
        return self._md.log_time_ns(t_s, self._base_s)

    def measurement(self, m: Measurement) -> None:
        """An accepted measurement, on its channel's topic."""
        with self._lock:
            cid = self._inputs.get(m.channel)
            if cid is None:
                cid = self._inputs[m.channel] = self._recorder.add_channel(f"/{m.channel}", self._md.channel_schema(m.channel))
        self._recorder.write(cid, self._ns(m.t_s), self._md.encode_row(m.channel, m.values))

    def estimate(self, name: str, row: OutputRow) -> None:
        """A published row of estimator ``name`` (its channel is created at its first row, with the fields that row has)."""
        md = self._md
        with self._lock:
            ids = self._estimates.get(name)
            if ids is None:
                fields = [f for f in _OPTIONAL_FIELDS if getattr(row, f) is not None]
                ids = self._estimates[name] = (
                    self._recorder.add_channel(f"/estimates/{name}", md.estimate_schema(), md.estimate_channel_metadata(name, fields, float("nan"))),
                    self._recorder.add_channel(f"/estimates/{name}/fix", md.LOCATION_FIX_SCHEMA),
                    self._recorder.add_channel(f"/estimates/{name}/pose", md.POSE_IN_FRAME_SCHEMA),
                )
        t_ns = self._ns(row.t_s)
        var = None if row.cov_en_m2 is None else (float(row.cov_en_m2[0, 0]), float(row.cov_en_m2[1, 1]))
        self._recorder.write(ids[0], t_ns, md.encode_estimate_row(row))
        self._recorder.write(ids[1], t_ns, md.location_fix_payload(t_ns, row.east_m, row.north_m, var, self._origin, name))
        self._recorder.write(ids[2], t_ns, md.pose_payload(t_ns, row.east_m, row.north_m, row.yaw_rad))

    def latency(self, name: str, m: Measurement, seq: int | None, latency_ms: float, outputs: int) -> None:
        """One measurement's receipt-to-publish latency in estimator ``name``."""
        with self._lock:
            cid = self._latency.get(name)
            if cid is None:
                cid = self._latency[name] = self._recorder.add_channel(f"/live/{name}/latency", _LATENCY_SCHEMA)
        body = {"t_s": m.t_s, "channel": m.channel, "seq": seq, "latency_ms": latency_ms, "outputs": outputs}
        self._recorder.write(cid, self._ns(m.t_s), json.dumps(body).encode())

    def status(self, status: dict[str, Any]) -> None:
        """The session's status (once a second)."""
        self._recorder.write(self._status, self._ns(status.get("t_s") or 0.0), json.dumps(status, default=float).encode())

    def rejected(self, payload: bytes, reason: str, kind: str, source: str) -> None:
        """A malformed message, raw."""
        raw = payload[:_MAX_RAW_BYTES].decode("utf-8", "backslashreplace")
        body = {"reason": reason, "kind": kind, "source": source, "payload": raw}
        self._recorder.write(self._rejected, 0, json.dumps(body).encode())

    def close(self) -> None:
        """Close the file whole (summary and footer)."""
        self._recorder.close()
