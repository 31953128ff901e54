"""Estimates to Foxglove as they are produced: a WebSocket server of the ``foxglove-sdk`` package.

Open Foxglove, *Open connection*, *Foxglove WebSocket*, ``ws://HOST:PORT``
(default ``ws://localhost:8765``). Topics, per estimator ``NAME``:

- ``/estimates/NAME/fix``: ``foxglove.LocationFix`` (the Map panel), with
  the east/north covariance and the estimator's colour
  (:func:`graphpos.colors.rgb_of`, the one of the report plots);
- ``/estimates/NAME/pose``: ``foxglove.PoseInFrame`` in frame ``enu``
  (the 3D panel);
- ``/estimates/NAME``: the estimate itself as JSON (schema
  ``graphpos.estimate``: east, north, velocity, yaw, covariance);

and ``/live/status`` (JSON: the network counts, each estimator's lag and
latency; once a second) and ``/map`` (``foxglove.GeoJSON``: the tags and
RSUs, sent again every :data:`MAP_EVERY_S` so that a viewer that connects
later sees them). Log times are the drive's ``t_s`` in nanoseconds.
"""

from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

from graphpos.colors import rgb_of
from graphpos.drive import Drive
from graphpos.errors import ConfigError
from graphpos.estimate import OutputRow
from graphpos.io.geo import enu_to_geodetic

#: Seconds between two sendings of the map.
MAP_EVERY_S = 5.0


class FoxgloveOutput:
    """A Foxglove WebSocket server publishing each estimate row of the estimators ``names``.

    Raises
    ------
    ConfigError
        The port cannot be bound.
    """

    def __init__(self, site: Drive, names: list[str], host: str = "127.0.0.1", port: int = 8765):
        import foxglove
        from foxglove.channels import LocationFixChannel, PoseInFrameChannel

        from graphpos.io.mcap_drive import GEOJSON_SCHEMA, map_geojson_payload

        self._fg = foxglove
        self._LocationFixChannel, self._PoseInFrameChannel = LocationFixChannel, PoseInFrameChannel
        self._context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name="graphpos live", host=host, port=port, context=self._context)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types for a port in use
            raise ConfigError(f"cannot start the Foxglove server on {host}:{port}: {exc}") from None
        self.port = self.server.port
        self._origin = site.origin
        self._channels: dict[str, tuple] = {}
        self._lock = threading.Lock()
        self._status = foxglove.Channel("/live/status", schema={"type": "object", "title": "graphpos.live_status"}, context=self._context)
        self._map = foxglove.Channel("/map", message_encoding="json", context=self._context,
                                     schema=foxglove.Schema(name="foxglove.GeoJSON", encoding="jsonschema",
                                                            data=json.dumps(GEOJSON_SCHEMA).encode()))
        self._map_payload = map_geojson_payload(site, site.origin)
        self._map_sent = -math.inf
        for name in names:  # every channel before any viewer connects: one advertisement, no subscription racing a new channel
            self._channels_of(name)

    def _channels_of(self, name: str) -> tuple:
        with self._lock:
            if name not in self._channels:
                from graphpos.io.mcap_drive import estimate_schema

                self._channels[name] = (
                    self._LocationFixChannel(f"/estimates/{name}/fix", context=self._context),
                    self._PoseInFrameChannel(f"/estimates/{name}/pose", context=self._context),
                    self._fg.Channel(f"/estimates/{name}", schema=estimate_schema(), context=self._context),
                )
            return self._channels[name]

    def estimate(self, name: str, row: OutputRow) -> None:
        from foxglove.messages import Color, LocationFix, Pose, PoseInFrame, Quaternion, Timestamp, Vector3
        from foxglove.messages import LocationFixPositionCovarianceType as CovarianceType

        fix_ch, pose_ch, json_ch = self._channels_of(name)
        t_ns = max(0, int(round(row.t_s * 1e9)))
        stamp = Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)
        lat, lon = enu_to_geodetic(row.east_m, row.north_m, self._origin)
        cov = [0.0] * 9
        if row.cov_en_m2 is not None:
            cov[0], cov[1], cov[3], cov[4] = (float(v) for v in row.cov_en_m2.reshape(-1))
        r, g, b = rgb_of(name)
        fix_ch.log(LocationFix(timestamp=stamp, frame_id="enu", latitude=float(lat), longitude=float(lon), altitude=0.0,
                               position_covariance=cov,
                               position_covariance_type=CovarianceType.Known if row.cov_en_m2 is not None else CovarianceType.Unknown,
                               color=Color(r=r, g=g, b=b, a=1.0)), log_time=t_ns)
        yaw = row.yaw_rad if row.yaw_rad is not None and row.yaw_rad == row.yaw_rad else 0.0
        pose_ch.log(PoseInFrame(timestamp=stamp, frame_id="enu",
                                pose=Pose(position=Vector3(x=row.east_m, y=row.north_m, z=0.0),
                                          orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))),
                    log_time=t_ns)
        json_ch.log(row.to_dict(), log_time=t_ns)

    def status(self, status: dict[str, Any]) -> None:
        t_ns = max(0, int(round((status.get("t_s") or 0.0) * 1e9)))
        self._status.log(json.loads(json.dumps(status, default=float)), log_time=t_ns)
        now = time.monotonic()
        if now - self._map_sent >= MAP_EVERY_S:
            self._map.log(self._map_payload, log_time=t_ns)
            self._map_sent = now

    def close(self) -> None:
        self.server.stop()
