"""Every estimator takes the gyro bias seen at a standstill off its yaw rates (graphpos.standstill).

A drive that begins standing for 15 s, then runs 45 s without a compass and
through a stretch without tags, so that the heading rests on the gyro. Its
wheel encoders read exactly zero while the vehicle stands (as encoders do).
With a 0.4 deg/s gyro bias added, each estimator must do as well as on the
unbiased drive; with the correction switched off it must not (the test can
fail).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from graph_drives import position_errors, rms, run, synthetic_drive

from graphpos.drive import Drive
from graphpos.standstill import StandstillGyroBias

BIAS_RADPS = math.radians(0.4)


@functools.lru_cache(maxsize=None)
def standing_start() -> Drive:
    drive = synthetic_drive(60.0, seed=1, stop=(0.0, 15.0), compass=False, turn_radps=0.05, tag_gap=(40.0, 120.0))
    wheel, truth = drive.wheel, drive.truth
    standing = np.interp(wheel.t_s, truth.t_s, np.hypot(truth.v_east_mps, truth.v_north_mps)) == 0.0
    return drive.replace(channels={**drive.channels, "wheel": wheel.replace(speed_mps=np.where(standing, 0.0, wheel.speed_mps))})


def biased(drive: Drive) -> Drive:
    return drive.replace(channels={**drive.channels, "imu": drive.imu.replace(yaw_rate_radps=drive.imu.yaw_rate_radps + BIAS_RADPS)})


@pytest.mark.parametrize("key", ["fusion-ekf", "dr", "graph-isam2/planar", "graph-batch/planar"])
def test_a_standstill_bias_costs_nothing(key):
    drive = standing_start()
    clean = rms(position_errors(drive, run(key, drive)))
    est = run(key, biased(drive))
    found = est.diagnostics["standstill"]
    assert found["standstills"] == 1
    assert abs(found["gyro_bias_radps"] - BIAS_RADPS) < 4 * found["gyro_bias_sigma_radps"] + math.radians(0.01)
    assert rms(position_errors(drive, est)) <= 1.1 * clean + 0.02


@pytest.mark.parametrize("key", ["fusion-ekf", "graph-isam2/planar"])
def test_without_the_correction_the_bias_costs_metres(key, monkeypatch):
    drive = standing_start()
    clean = rms(position_errors(drive, run(key, drive)))
    monkeypatch.setattr(StandstillGyroBias, "yaw_rate", lambda self, t_s, yaw_rate_radps: yaw_rate_radps)
    assert rms(position_errors(drive, run(key, biased(drive)))) > 3.0 * clean + 1.0
