"""Shared helpers of the I/O tests: drive/estimate comparison and a
hand-built drive with every channel."""

from __future__ import annotations

import numpy as np

from graphpos.drive import CHANNEL_SPECS, Channel, Drive, GeoOrigin, RsuMap, TagMap, Window
from graphpos.estimate import Estimate


def assert_drives_equal(a: Drive, b: Drive) -> None:
    """Every array bit-exact (NaN where NaN), maps, windows, origin, params."""
    assert a.name == b.name
    assert list(a.channels) == list(b.channels)
    for kind, ch in a.channels.items():
        other = b.channels[kind]
        for spec in CHANNEL_SPECS[kind]:
            x, y = ch[spec.name], other[spec.name]
            assert x.dtype == y.dtype == np.float64
            # bit-exact: compare the raw bytes (distinguishes -0.0, NaN payloads aside)
            assert np.array_equal(np.isnan(x), np.isnan(y)), (kind, spec.name)
            assert x[~np.isnan(x)].tobytes() == y[~np.isnan(y)].tobytes(), (kind, spec.name)
    assert a.tags == b.tags
    assert a.rsus == b.rsus
    assert a.windows == b.windows
    assert a.origin == b.origin
    assert a.params == b.params


def assert_estimates_equal(a: Estimate, b: Estimate) -> None:
    assert a.name == b.name
    for field in ("t_s", "east_m", "north_m", "v_east_mps", "v_north_mps", "yaw_rad", "cov_en_m2"):
        x, y = getattr(a, field), getattr(b, field)
        assert (x is None) == (y is None), field
        if x is not None:
            assert np.array_equal(x, y, equal_nan=True), field
    assert np.array_equal([a.rate_hz, a.wall_time_s], [b.rate_hz, b.wall_time_s], equal_nan=True)
    assert a.diagnostics == b.diagnostics


def every_channel_drive(n: int = 500, seed: int = 3) -> Drive:
    """A small drive with every channel, NaN columns, late readings, layouts,
    windows, an RSU map with fixes and ranges, awkward floats."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(n) * 0.01 + 1e-3, 6)
    t10 = t[::10]
    tags = TagMap(
        [0, 1, 2, 7],
        [0.0, 6.0, 12.0, 18.000000000000004],
        [3.0, -3.0, 3.0, -3.0],
        [1, -1, 1, -1],
        [0, 0, 1, -1],
        layouts={"optimized": [0, 2], "sparse": [7]},
    )
    rsus = RsuMap([10, 11], [0.0, 250.5], [-7.25, 7.25])
    k = t10.size
    accel_y = rng.normal(0, 0.1, n)
    accel_y[::7] = np.nan
    channels = {
        "imu": Channel("imu", {
            "t_s": t, "accel_x_mps2": rng.normal(0, 0.1, n) * 1e-3,
            "accel_y_mps2": accel_y, "yaw_rate_radps": rng.normal(0, 0.003, n),
        }),
        "wheel": Channel("wheel", {"t_s": t, "speed_mps": np.abs(rng.normal(20, 0.1, n))}),
        "compass": Channel("compass", {"t_s": t10, "yaw_rad": rng.uniform(-np.pi, np.pi, k)}),
        "rfid": Channel("rfid", {
            "t_s": np.repeat(t10, 2),
            "tag_id": np.tile([0, 7], k),
            "rss": np.where(np.arange(2 * k) % 3 == 0, np.nan, rng.integers(0, 256, 2 * k)),
            "range_m": np.where(np.arange(2 * k) % 2 == 0, rng.uniform(0, 9, 2 * k), np.nan),
            "true_range_m": rng.uniform(0, 9, 2 * k),
            "arrival_s": np.repeat(t10, 2) + rng.uniform(0, 0.5, 2 * k),
        }),
        "rsu": Channel("rsu", {
            "t_s": t10,
            "rsu_id": np.where(np.arange(k) % 2 == 0, 10, 11),
            "east_m": np.where(np.arange(k) % 2 == 0, rng.normal(0, 1, k), np.nan),
            "north_m": np.where(np.arange(k) % 2 == 0, rng.normal(0, 1, k), np.nan),
            "range_m": np.where(np.arange(k) % 2 == 0, np.nan, rng.uniform(0, 100, k)),
            "sigma_m": np.full(k, 0.5),
            "arrival_s": t10 + 0.25,
        }),
        "gnss": Channel("gnss", {"t_s": t10, "east_m": rng.normal(0, 5, k), "north_m": -0.0 * t10, "sigma_m": np.full(k, 3.0)}),
        "truth": Channel("truth", {
            "t_s": t, "east_m": 20 * t + 0.1, "north_m": np.sin(t), "v_east_mps": np.full(n, 20.0),
            "v_north_mps": np.cos(t), "yaw_rad": np.arctan2(np.cos(t), 20.0),
            "yaw_rate_radps": np.full(n, np.nan), "accel_x_mps2": np.zeros(n), "accel_y_mps2": np.full(n, 1 / 3),
        }),
    }
    return Drive(
        name="every-channel",
        channels=channels,
        tags=tags,
        rsus=rsus,
        windows=(Window("in_tunnel", 1.0, 3.0), Window("zone:open", 0.0, 1.0)),
        origin=GeoOrigin(40.44, -79.94, 270.5),
        params={"scenario": "hand-built", "seed": seed, "nested": {"sigma": 0.1, "list": [1, 2.5]}},
    )
