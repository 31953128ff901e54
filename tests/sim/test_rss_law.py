"""The RSS law's terms (issue 20; graphpos/sim/rss.py): each has the shape its physics gives."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.sim.rss import ENVIRONMENTS


@pytest.mark.parametrize("name", list(ENVIRONMENTS))
def test_law_stays_on_the_scale_and_falls_overall(name):
    env = ENVIRONMENTS[name]
    d = np.linspace(0.05, 9.0, 500)
    m = env.mean_rss(d)
    assert np.all((m > 0) & (m < 255))
    assert m[d >= 1.0][0] - m[-1] > 30  # loses a lot over 1-9 m
    # near range: flattened by the antenna pattern and the saturation, not +6 dB per halving
    assert abs(env.mean_rss(0.1) - env.mean_rss(0.3)) < 0.5 * 9.5 * env.units_per_db


def test_front_end_saturates_and_levels_off_on_the_noise_floor():
    env = ENVIRONMENTS["outdoor"]
    strong = env.front_end(np.array([20.0, 30.0, 60.0]))
    assert np.all(strong <= env.saturation_rss) and strong[2] - strong[1] < 0.5
    weak = env.front_end(env.noise_floor_db + np.array([-20.0, -30.0]))
    assert abs(weak[0] - weak[1]) < 0.2 * env.units_per_db


def test_outdoor_two_ray_falls_faster_beyond_the_break():
    env = ENVIRONMENTS["outdoor"]
    near_slope = (env.signal_db(2.0) - env.signal_db(1.0)) / np.log10(2.0)
    far_slope = (env.signal_db(9.0) - env.signal_db(4.5)) / np.log10(2.0)
    assert far_slope < near_slope - 5.0  # dB per decade: steeper far out


def test_tunnel_ripple_is_deterministic_structure():
    env = ENVIRONMENTS["tunnel"]
    d = np.arange(3.0, 9.0, 0.05)
    residual = env.signal_db(d) + 10 * env.path_loss_exponent * np.log10(d)
    rises = np.sum(np.diff(env.mean_rss(d)) > 0)
    assert np.ptp(residual) > 3.0 and rises > 0  # the wall interference makes the curve non-monotonic


def test_sampling_adds_fading_before_the_front_end():
    env = ENVIRONMENTS["laboratory"]
    rng = np.random.default_rng(0)
    d = np.full(20000, 3.0)
    samples = env.sample_rss(d, rng)
    assert samples.mean() == pytest.approx(env.mean_rss(3.0), abs=1.0)
    assert samples.std() == pytest.approx(env.units_per_db * env.fading_db, rel=0.1)
