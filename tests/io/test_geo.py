"""WGS84 <-> the local east-north frame (graphpos.io.geo, on pymap3d), 30 km
from the origin: against pymap3d itself, against the ellipsoid geometry
computed by hand (ECEF positions, a meridian arc) within a centimetre, and
round trips."""

from __future__ import annotations

import numpy as np
import pymap3d
import pymap3d.vincenty
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from graphpos.drive import GeoOrigin
from graphpos.io.geo import enu_to_geodetic, geodetic_to_enu

ORIGIN = GeoOrigin(29.563, 106.5516, 250.0)
#: WGS84 semi-major axis and first eccentricity squared.
A_M, E2 = 6378137.0, 6.69437999014e-3
#: About 30 km north, 30 km east, 30 km south-west of the origin, at other heights.
LAT_DEG = np.array([ORIGIN.lat_deg + 0.2707, ORIGIN.lat_deg, ORIGIN.lat_deg - 0.19])
LON_DEG = np.array([ORIGIN.lon_deg, ORIGIN.lon_deg + 0.3107, ORIGIN.lon_deg - 0.22])
ALT_M = np.array([250.0, 310.0, 180.0])


def _ecef_m(lat_deg, lon_deg, alt_m):
    """Earth-centred position of a geodetic one (the textbook formula)."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    prime_vertical_m = A_M / np.sqrt(1 - E2 * np.sin(lat) ** 2)
    return np.stack([(prime_vertical_m + alt_m) * np.cos(lat) * np.cos(lon),
                     (prime_vertical_m + alt_m) * np.cos(lat) * np.sin(lon),
                     (prime_vertical_m * (1 - E2) + alt_m) * np.sin(lat)], axis=-1)


def test_same_as_pymap3d():
    east, north, up = geodetic_to_enu(LAT_DEG, LON_DEG, ORIGIN, ALT_M)
    want = pymap3d.geodetic2enu(LAT_DEG, LON_DEG, ALT_M, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    np.testing.assert_allclose(np.stack([east, north, up]), np.stack(want), rtol=0, atol=1e-9)
    assert 29_000 < np.hypot(east, north).min() and np.hypot(east, north).max() < 35_000
    lat, lon = enu_to_geodetic(east, north, ORIGIN, up)
    want_lat, want_lon, _ = pymap3d.enu2geodetic(east, north, up, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    np.testing.assert_allclose(np.stack([lat, lon]), np.stack([want_lat, want_lon]), rtol=0, atol=1e-12)


def test_enu_is_the_ellipsoid_geometry_by_hand_within_a_centimetre():
    east, north, up = geodetic_to_enu(LAT_DEG, LON_DEG, ORIGIN, ALT_M)
    offset_m = _ecef_m(LAT_DEG, LON_DEG, ALT_M) - _ecef_m(ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    lat0, lon0 = np.radians(ORIGIN.lat_deg), np.radians(ORIGIN.lon_deg)
    axes = {"east": [-np.sin(lon0), np.cos(lon0), 0.0],
            "north": [-np.sin(lat0) * np.cos(lon0), -np.sin(lat0) * np.sin(lon0), np.cos(lat0)],
            "up": [np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)]}
    for got, axis in zip((east, north, up), axes.values()):
        np.testing.assert_allclose(got, offset_m @ np.array(axis), rtol=0, atol=0.01)
    np.testing.assert_allclose(np.sqrt(east**2 + north**2 + up**2), np.linalg.norm(offset_m, axis=1), rtol=0, atol=0.01)
    # a point on the origin's parallel 30 km east is 40 m north of the east axis: the parallel
    # curves away from the tangent plane's straight line (a flat-earth scaling puts it on the axis)
    assert north[1] == pytest.approx(east[1] ** 2 * np.tan(lat0) / (2 * 6_380_000), rel=0.02)
    assert north[1] > 30


def test_a_fix_30_km_up_the_meridian():
    def arc_m(lat_deg):  # meridian arc length from the origin's latitude, by quadrature
        def meridional_radius_m(lat):
            return A_M * (1 - E2) / (1 - E2 * np.sin(lat) ** 2) ** 1.5
        return quad(meridional_radius_m, np.radians(ORIGIN.lat_deg), np.radians(lat_deg), epsabs=1e-6)[0]

    lat_deg = brentq(lambda lat: arc_m(lat) - 30_000.0, ORIGIN.lat_deg, ORIGIN.lat_deg + 1.0, xtol=1e-12)
    distance_m, _ = pymap3d.vincenty.vdist(ORIGIN.lat_deg, ORIGIN.lon_deg, lat_deg, ORIGIN.lon_deg)
    assert float(distance_m) == pytest.approx(30_000.0, abs=0.01)
    east, north, up = geodetic_to_enu(lat_deg, ORIGIN.lon_deg, ORIGIN, ORIGIN.alt_m)
    assert abs(float(east)) < 1e-6
    # the chord of a 30 km arc of the meridian (radius about 6 352 km, taken halfway), at the
    # origin's height: 1 m longer than the arc on the ellipsoid, 71 m below the tangent plane
    radius_m = A_M * (1 - E2) / (1 - E2 * np.sin(np.radians((ORIGIN.lat_deg + lat_deg) / 2)) ** 2) ** 1.5
    angle = 30_000.0 / radius_m
    radius_m += ORIGIN.alt_m
    assert float(north) == pytest.approx(radius_m * np.sin(angle), abs=0.01)
    assert float(up) == pytest.approx(-radius_m * (1 - np.cos(angle)), abs=0.01)


def test_round_trips():
    east, north, up = geodetic_to_enu(LAT_DEG, LON_DEG, ORIGIN, ALT_M)
    lat, lon = enu_to_geodetic(east, north, ORIGIN, up)
    np.testing.assert_allclose(np.stack([lat, lon]), np.stack([LAT_DEG, LON_DEG]), rtol=0, atol=1e-10)
    # a drive's positions (in the tangent plane) and back, at the height the plane has there
    plane_e, plane_n = np.array([30_000.0, -12_000.0, 0.0]), np.array([0.0, 27_000.0, -30_000.0])
    lat, lon = enu_to_geodetic(plane_e, plane_n, ORIGIN)
    _, _, height_m = pymap3d.enu2geodetic(plane_e, plane_n, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    back_e, back_n, back_u = geodetic_to_enu(lat, lon, ORIGIN, height_m)
    np.testing.assert_allclose(np.stack([back_e, back_n, back_u]), np.stack([plane_e, plane_n, np.zeros(3)]), rtol=0, atol=1e-3)
    # scalars stay scalars; the default height is the origin's
    e, n, u = geodetic_to_enu(ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN)
    assert np.ndim(e) == 0 and abs(float(e)) + abs(float(n)) + abs(float(u)) < 1e-9
