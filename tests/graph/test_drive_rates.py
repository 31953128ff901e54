"""The sample rates that turn per-sample sigmas into noise densities: measured on the drive, or given."""

from __future__ import annotations

import numpy as np
import pytest
from graph_drives import SYNTHETIC_MODEL, synthetic_drive

from graphpos.drive import Channel
from graphpos.errors import ConfigError
from graphpos.graph import ESTIMATORS
from graphpos.graph.config import GraphConfig
from graphpos.io.checks import drive_checks, new_reading_rate_hz


def test_new_readings_are_counted_once_per_run():
    t = np.arange(0.0, 20.0, 0.01)
    rng = np.random.default_rng(0)
    assert new_reading_rate_hz(t, rng.normal(size=t.size)) == pytest.approx((100.0, 100.0))
    held = np.repeat(rng.normal(size=t.size // 10), 10)
    assert new_reading_rate_hz(t, held) == pytest.approx((100.0, 10.0))
    held[: t.size // 2] = 0.0  # 10 s standing still: one run of 1000 rows, which the median does not see
    assert new_reading_rate_hz(t, held) == pytest.approx((100.0, 10.0))
    assert new_reading_rate_hz(t[:2], held[:2]) is None
    assert new_reading_rate_hz(np.full(5, 2.0), np.arange(5.0)) is None


def _held(channel: Channel, column: str, times: int) -> Channel:
    """The channel logged ``times`` times as often, each reading repeated until the next (a logger that holds values)."""
    dt = float(np.median(np.diff(channel.t_s))) / times
    fine = (channel.t_s[:, None] + dt * np.arange(times)[None, :]).ravel()
    return Channel(channel.kind, {"t_s": fine, column: np.repeat(channel.columns[column], times)})


def _held_drive():
    drive = synthetic_drive(30, seed=3, tag_gap=(40.0, 110.0)).without_truth()  # 14 s on the wheel alone
    return drive, drive.replace(channels={**drive.channels, "wheel": _held(drive.channels["wheel"], "speed_mps", 4)})


def test_a_held_wheel_is_warned_of():
    """MRCLAM logs commanded speeds at 100 Hz that change about 11 times a second: the drive check says so."""
    drive, held = _held_drive()
    message = {c["name"]: c["message"] for c in drive_checks(held)}["held-readings"]
    assert message is not None and "--set wheel_rate_hz=100" in message and "400.0 rows/s" in message
    assert {c["name"]: c["message"] for c in drive_checks(drive)}["held-readings"] is None


@pytest.mark.parametrize("name", ["graph-isam2", "graph-batch"])
def test_a_given_wheel_rate_is_kept_and_held_readings_count_once_in_graph_batch(name):
    """The repeats of a held reading are no new readings, and repeat its error.

    graph-batch counts the new readings by itself: on the drive logged four
    times over it is what it is on the drive logged once per reading.
    graph-isam2 counts rows (its own calibration and the profiles it is
    given are fitted that way, :class:`~graphpos.graph.estimators.GraphBatch`),
    so there the row rate makes the wheel 2x too precise, until the rate of
    new readings is given as ``wheel_rate_hz`` (what the drive check prints).
    """
    drive, held = _held_drive()
    # graph-isam2 with its noise levels as configured: neither learnt online nor widened by its check (nor for an
    # uncalibrated wheel, whose scale term would hide the white noise's count)
    online = {"learn_online": False, "covariance_check": False,
              "uncalibrated_wheel_scale_density_per_sqrt_s": SYNTHETIC_MODEL["wheel_scale_density_per_sqrt_s"]} if name == "graph-isam2" else {}

    def run(d, **config):
        est = ESTIMATORS[name](GraphConfig(parameterisation="planar", **SYNTHETIC_MODEL, **online, **config))
        return est, est.run(d)

    est_plain, plain = run(drive)
    est_measured, measured = run(held)
    est_given, given = run(held, wheel_rate_hz=100.0)
    assert est_plain.config.wheel_rate_hz == pytest.approx(100.0)
    assert est_measured.config.wheel_rate_hz == pytest.approx(100.0 if name == "graph-batch" else 400.0)
    assert est_given.config.wheel_rate_hz == 100.0

    def spread(est):
        """Along-track (east) variance gained in the gap, where the wheel alone carries the track (after the start's 5 s)."""
        late = est.t_s > 5.0
        v = est.cov_en_m2[:, 0, 0]
        peak = int(np.argmax(np.where(late, v, -np.inf)))
        return float(v[peak] - v[late & (est.t_s <= est.t_s[peak])].min())

    assert spread(given) == pytest.approx(spread(plain), rel=0.05)
    assert np.hypot(given.east_m - plain.east_m, given.north_m - plain.north_m).max() < 0.02
    if name == "graph-batch":
        assert spread(measured) == pytest.approx(spread(plain), rel=0.05)
    else:
        assert spread(measured) < 0.85 * spread(plain)


@pytest.mark.parametrize("rate", [0.0, -5.0, float("nan"), float("inf")])
def test_a_rate_must_be_positive_or_none(rate):
    with pytest.raises(ConfigError, match="wheel_rate_hz"):
        GraphConfig(wheel_rate_hz=rate)
    assert GraphConfig(imu_rate_hz=None).imu_rate_hz is None
