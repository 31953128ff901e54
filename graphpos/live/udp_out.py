"""Estimates as UDP JSON: one datagram per estimate row, for a program that wants them without Foxglove.

Each datagram is one JSON object::

    {"estimator": "graph-isam2", "t_s": 12.3, "east_m": 4.56, "north_m": -1.2, "lat_deg": 40.44, "lon_deg": -79.94,
     "v_east_mps": 1.9, "v_north_mps": 0.1, "yaw_rad": 0.05, "cov_en_m2": [0.01, 0.0, 0.0, 0.02]}

(null where the estimator does not estimate a quantity; ``cov_en_m2`` is
the east/north position covariance, row-major). Status is not sent.
"""

from __future__ import annotations

import json
from typing import Any

from graphpos.drive import Drive
from graphpos.estimate import OutputRow
from graphpos.io.geo import enu_to_geodetic
from graphpos.live.sources import Address, sender


class UdpOutput:
    """Sends every estimate row to ``address`` (``udp://HOST:PORT``)."""

    def __init__(self, site: Drive, address: Address):
        self._send = sender(address)
        self._origin = site.origin
        self.errors = 0

    def estimate(self, name: str, row: OutputRow) -> None:
        lat, lon = enu_to_geodetic(row.east_m, row.north_m, self._origin)
        body = {"estimator": name, **row.to_dict(), "lat_deg": float(lat), "lon_deg": float(lon)}
        try:
            self._send(json.dumps(body).encode())
        except OSError:
            self.errors += 1  # nobody listening (yet): estimates are not held back for it

    def status(self, status: dict[str, Any]) -> None:
        pass

    def close(self) -> None:
        pass
