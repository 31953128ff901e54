"""The standstill gyro bias: measured while the wheels stand, causal, and blind to turns on the spot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graphpos.standstill import StandstillGyroBias


def feed(estimator: StandstillGyroBias, t_s: np.ndarray, speed_mps: np.ndarray, yaw_rate_radps: np.ndarray) -> np.ndarray:
    """Wheel speed then yaw rate at each epoch; the corrected yaw rates."""
    out = np.empty_like(yaw_rate_radps)
    for k, (t, v, w) in enumerate(zip(t_s, speed_mps, yaw_rate_radps)):
        estimator.speed(t, v)
        out[k] = estimator.yaw_rate(t, w)
    return out


def drive(seed: int, bias_radps: float, segments: list[tuple[float, float, float]], noise_radps: float = 0.002):
    """Epochs at 100 Hz over (duration_s, speed_mps, true_yaw_rate_radps) segments; gyro = truth + bias + noise."""
    rng = np.random.default_rng(seed)
    speed = np.concatenate([np.full(int(d * 100), v) for d, v, _ in segments])
    rate = np.concatenate([np.full(int(d * 100), w) for d, _, w in segments])
    t = np.arange(len(speed)) / 100.0
    return t, speed, rate + bias_radps + rng.normal(0.0, noise_radps, len(t)), rate


@pytest.mark.parametrize("seed", range(5))
def test_bias_from_a_standstill_within_its_sigma(seed):
    bias = math.radians(np.random.default_rng(100 + seed).uniform(-0.5, 0.5))
    t, v, w, _ = drive(seed, bias, [(20.0, 0.0, 0.0), (30.0, 5.0, 0.1)])
    est = StandstillGyroBias()
    feed(est, t, v, w)
    sigma = math.sqrt(est.variance_rad2ps2)
    assert est.standstills == 1
    assert abs(est.bias_radps - bias) < 4 * sigma
    assert sigma < math.radians(0.02)


def test_corrections_are_causal():
    t, v, w, true_rate = drive(0, math.radians(0.3), [(10.0, 5.0, 0.05), (10.0, 0.0, 0.0), (10.0, 5.0, -0.05)])
    corrected = feed(StandstillGyroBias(), t, v, w)
    before = t < 10.0
    np.testing.assert_array_equal(corrected[before], w[before])  # nothing known yet
    after = t > 20.5
    assert abs(np.mean(corrected[after] - true_rate[after])) < math.radians(0.02)


def test_turn_on_the_spot_is_not_a_bias():
    t, v, w, _ = drive(1, math.radians(0.2), [(10.0, 0.0, 0.3), (10.0, 1.0, 0.0)])
    est = StandstillGyroBias()
    feed(est, t, v, w)
    assert est.standstills == 0
    assert est.bias_radps == 0.0


def test_short_stops_and_non_finite_samples_are_ignored():
    t, v, w, _ = drive(2, math.radians(0.3), [(2.0, 0.0, 0.0), (5.0, 3.0, 0.0), (8.0, 0.0, 0.0), (5.0, 3.0, 0.0)])
    w[::7] = np.nan
    v[::11] = np.nan
    est = StandstillGyroBias()
    feed(est, t, v, w)
    assert est.standstills == 1  # the 2 s stop is shorter than margins plus min_duration_s
    assert abs(est.bias_radps - math.radians(0.3)) < math.radians(0.02)


def test_a_drifting_bias_is_followed():
    b0, b1 = math.radians(0.1), math.radians(0.4)
    t0, v0, w0, _ = drive(3, b0, [(10.0, 0.0, 0.0), (600.0, 10.0, 0.0)])
    t1, v1, w1, _ = drive(4, b1, [(10.0, 0.0, 0.0), (5.0, 10.0, 0.0)])
    est = StandstillGyroBias()
    feed(est, np.concatenate([t0, t1 + t0[-1] + 0.01]), np.concatenate([v0, v1]), np.concatenate([w0, w1]))
    assert est.standstills == 2
    assert abs(est.bias_radps - b1) < abs(est.bias_radps - b0)
