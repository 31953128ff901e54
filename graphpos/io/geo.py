"""East/north metres in a drive's local frame -> WGS84 latitude/longitude.

The conversion is a local tangent-plane (flat-earth) approximation about the
drive's :class:`~graphpos.drive.GeoOrigin`: north is scaled by the WGS84
meridional radius of curvature and east by the prime-vertical radius times
``cos(lat0)``, both taken at the origin's latitude. Over a few kilometres the
error is far below a metre (it grows with the square of the distance from the
origin), which is plenty for drawing a track on a map; positions are never
read back from latitude/longitude.
"""

from __future__ import annotations

import numpy as np

from graphpos.drive import GeoOrigin

_WGS84_A_M = 6378137.0
_WGS84_E2 = 6.69437999014e-3


def enu_to_geodetic(east_m: np.ndarray, north_m: np.ndarray, origin: GeoOrigin) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude (degrees) of local east/north positions.

    Parameters
    ----------
    east_m, north_m : array-like
        Positions in the local frame whose origin is ``origin``.
    origin : GeoOrigin
        Geodetic position of the local frame's origin.

    Returns
    -------
    lat_deg, lon_deg : ndarray
    """
    lat0 = np.radians(origin.lat_deg)
    s2 = np.sin(lat0) ** 2
    meridional_m = _WGS84_A_M * (1 - _WGS84_E2) / (1 - _WGS84_E2 * s2) ** 1.5
    prime_vertical_m = _WGS84_A_M / np.sqrt(1 - _WGS84_E2 * s2)
    lat = origin.lat_deg + np.degrees(np.asarray(north_m, dtype=np.float64) / meridional_m)
    lon = origin.lon_deg + np.degrees(np.asarray(east_m, dtype=np.float64) / (prime_vertical_m * np.cos(lat0)))
    return lat, lon
