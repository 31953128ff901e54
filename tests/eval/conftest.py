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
    """A vehicle on a straight line at constant speed, with truth, wheel speed, two windows and
    exact position fixes (``gnss`` at the truth's epochs: what :class:`NoisyTruth` reads, since
    estimators never see the truth)."""
    t = np.arange(0.0, duration_s + 1e-9, 0.1)
    ve, vn = speed_mps * np.cos(yaw_rad), speed_mps * np.sin(yaw_rad)
    truth = Channel(
        "truth",
        {"t_s": t, "east_m": ve * t, "north_m": vn * t, "v_east_mps": np.full_like(t, ve),
         "v_north_mps": np.full_like(t, vn), "yaw_rad": np.full_like(t, yaw_rad)},
    )
    wheel = Channel("wheel", {"t_s": t, "speed_mps": np.full_like(t, speed_mps + wheel_bias_mps)})
    gnss = Channel("gnss", {"t_s": t, "east_m": ve * t, "north_m": vn * t, "sigma_m": np.full_like(t, 1e-3)})
    tags = TagMap(np.arange(4), [0, 6, 0, 6], [3, 3, -3, -3], [1, 1, -1, -1], [0, 0, 0, 0])
    windows = (Window("in_tunnel", 2.0, 6.0), Window("zone:a", 0.0, 1.0), Window("zone:a", 8.0, 9.0))
    return Drive("straight", {"truth": truth, "wheel": wheel, "gnss": gnss}, tags=tags, windows=windows)


@pytest.fixture
def drive() -> Drive:
    return straight_drive()


@pytest.fixture
def make_drive():
    """The :func:`straight_drive` factory."""
    return straight_drive


class NoisyTruth(Estimator):
    """Test estimator: the exact fixes of :func:`straight_drive` (the truth's positions) plus seeded
    Gaussian noise of known covariance, at 10 Hz, with velocity and yaw from successive fixes (zero
    at the first). It reads ``gnss``, not the truth: the harness hides the truth from estimators."""

    name = "noisy-truth"
    required_channels = ("gnss",)
    sigma_m = 0.5

    @classmethod
    def default_config(cls):
        return None

    def start(self, drive):
        self._rng = np.random.default_rng(7)
        self._rows = []
        self._last = None

    def process(self, m):
        v = m.values
        ve = vn = 0.0
        if self._last is not None and m.t_s > self._last[0]:
            dt = m.t_s - self._last[0]
            ve, vn = (v["east_m"] - self._last[1]) / dt, (v["north_m"] - self._last[2]) / dt
        self._last = (m.t_s, v["east_m"], v["north_m"])
        e, n = self._rng.normal(0.0, self.sigma_m, 2)
        row = OutputRow(m.t_s, v["east_m"] + e, v["north_m"] + n, ve, vn, float(np.arctan2(vn, ve)),
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
