"""Fixtures of the I/O tests: a hand-built drive with every channel and an
estimate of it, the Plaza dataset (skipped when ../shared/data is absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from drive_samples import every_channel_drive

from graphpos.drive import Drive
from graphpos.estimate import Estimate

PLAZA1 = Path(__file__).resolve().parents[2] / "../shared/data/plaza/Plaza1.mat"


@pytest.fixture
def plaza1() -> Path:
    if not PLAZA1.exists():
        pytest.skip(f"Plaza dataset not found at {PLAZA1}")
    return PLAZA1.resolve()


@pytest.fixture
def drive() -> Drive:
    return every_channel_drive()


@pytest.fixture
def estimate(drive: Drive) -> Estimate:
    truth = drive.truth
    n = len(truth)
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 0, 1], cov[:, 1, 0] = 0.5, 0.25, 0.01, 0.01000000001
    return Estimate(
        name="fusion-ekf",
        t_s=truth.t_s,
        east_m=truth.east_m + 0.1,
        north_m=truth.north_m - 0.2,
        v_east_mps=truth.v_east_mps,
        v_north_mps=truth.v_north_mps,
        yaw_rad=np.where(np.arange(n) < 5, np.nan, truth.yaw_rad),
        cov_en_m2=cov,
        rate_hz=100.0,
        diagnostics={"gated": 3, "note": "ok"},
        wall_time_s=0.125,
    )
