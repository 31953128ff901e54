"""WGS84 latitude/longitude <-> east/north metres in a drive's local frame.

The local frame is the east-north-up (ENU) tangent frame at the drive's
:class:`~graphpos.drive.GeoOrigin`: a rigid rotation of the earth-centred
(ECEF) frame about the origin, computed on the WGS84 ellipsoid by
``pymap3d`` (``geodetic2enu`` / ``enu2geodetic``). It is exact at any
distance: a GNSS fix tens of kilometres from the origin lands where the
ellipsoid puts it (a flat-earth scaling of latitude and longitude is off by
tens of metres there). The drive is 2-D: its positions lie in the tangent
plane (``up`` 0) unless a caller gives their height above it. The plane
rises above the ellipsoid with the distance from the origin (71 m at 30
km), so an exact round trip through latitude/longitude passes that height
back (:func:`geodetic_to_enu` at the origin's height lands 0.3 m off at 30
km).
"""

from __future__ import annotations

import numpy as np
import pymap3d

from graphpos.drive import GeoOrigin


def geodetic_to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, origin: GeoOrigin,
                    alt_m: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local east/north/up of geodetic positions (a GNSS fix into the drive's frame).

    Parameters
    ----------
    lat_deg, lon_deg : array-like
        WGS84 latitude and longitude in degrees.
    origin : GeoOrigin
        Geodetic position of the local frame's origin.
    alt_m : array-like or float, optional
        Height above the WGS84 ellipsoid in metres (default: the origin's).

    Returns
    -------
    east_m, north_m, up_m : ndarray
    """
    alt = origin.alt_m if alt_m is None else np.asarray(alt_m, dtype=np.float64)
    east, north, up = pymap3d.geodetic2enu(np.asarray(lat_deg, dtype=np.float64), np.asarray(lon_deg, dtype=np.float64), alt,
                                           origin.lat_deg, origin.lon_deg, origin.alt_m)
    return np.asarray(east, dtype=np.float64), np.asarray(north, dtype=np.float64), np.asarray(up, dtype=np.float64)


def enu_to_geodetic(east_m: np.ndarray, north_m: np.ndarray, origin: GeoOrigin,
                    up_m: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude (degrees) of local east/north positions.

    Parameters
    ----------
    east_m, north_m : array-like
        Positions in the local frame whose origin is ``origin``.
    origin : GeoOrigin
        Geodetic position of the local frame's origin.
    up_m : array-like or float
        Height above the tangent plane (0: a drive's positions).

    Returns
    -------
    lat_deg, lon_deg : ndarray
        NaN latitude where a position is too far from the earth to place
        (an estimate that diverged to 1e200 m), without a warning.
    """
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        lat, lon, _ = pymap3d.enu2geodetic(np.asarray(east_m, dtype=np.float64), np.asarray(north_m, dtype=np.float64),
                                           up_m, origin.lat_deg, origin.lon_deg, origin.alt_m)
    return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
