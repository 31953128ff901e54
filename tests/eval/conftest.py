"""Fixtures of the evaluation tests: tiny hand-made drives."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graphpos.drive import Channel, Drive, TagMap, Window
from graphpos.estimate import Estimate, OutputRow
from graphpos.estimator import Estimator

PLAZA = Path(__file__).resolve().parents[2] / "../shared/data/plaza/Plaza1.mat"


def straight_drive(duration_s: float = 10.0, speed_mps: float = 2.0, yaw_rad: float = 0.0, wheel_bias_mps: float = 0.1) -> Drive:
    """A vehicle on a straight line at constant speed, with truth, wheel speed and two windows."""
    t = np.arange(0.0, duration_s + 1e-9, 0.1)
    ve, vn = speed_mps * np.cos(yaw_rad), speed_mps * np.sin(yaw_rad)
    truth = Channel(
        "truth",
        {"t_s": t, "east_m": ve * t, "north_m": vn * t, "v_east_mps": np.full_like(t, ve),
         "v_north_mps": np.full_like(t, vn), "yaw_rad": np.full_like(t, yaw_rad)},
    )
    wheel = Channel("wheel", {"t_s": t, "speed_mps": np.full_like(t, speed_mps + wheel_bias_mps)})
    tags = TagMap(np.arange(4), [0, 6, 0, 6], [3, 3, -3, -3], [1, 1, -1, -1], [0, 0, 0, 0])
    windows = (Window("in_tunnel", 2.0, 6.0), Window("zone:a", 0.0, 1.0), Window("zone:a", 8.0, 9.0))
    return Drive("straight", {"truth": truth, "wheel": wheel}, tags=tags, windows=windows)


@pytest.fixture
def drive() -> Drive:
    return straight_drive()


@pytest.fixture
def make_drive():
    """The :func:`straight_drive` factory."""
    return straight_drive


class NoisyTruth(Estimator):
    """Test estimator: truth plus seeded Gaussian noise of known covariance, at 10 Hz, with velocity."""

    name = "noisy-truth"
    required_channels = ("truth",)
    sigma_m = 0.5

    @classmethod
    def default_config(cls):
        return None

    def start(self, drive):
        self._rng = np.random.default_rng(7)
        self._rows = []

    def process(self, m):
        v = m.values
        e, n = self._rng.normal(0.0, self.sigma_m, 2)
        row = OutputRow(m.t_s, v["east_m"] + e, v["north_m"] + n, v["v_east_mps"], v["v_north_mps"], v["yaw_rad"],
                        np.eye(2) * self.sigma_m**2)
        self._rows.append(row)
        return [row]

    def finish(self):
        return Estimate.from_rows(self.name, self._rows, rate_hz=10.0)


class Broken(NoisyTruth):
    """Test estimator that always fails."""

    name = "broken"

    def process(self, m):
        raise RuntimeError("boom")


@pytest.fixture
def test_estimators(monkeypatch):
    """Register the test estimators (forked pool workers and in-process Dask threads inherit this)."""
    import graphpos.registry

    classes = {**graphpos.registry.estimator_classes(), "noisy-truth": NoisyTruth, "broken": Broken}
    monkeypatch.setattr(graphpos.registry, "estimator_classes", lambda: classes)
    return classes
