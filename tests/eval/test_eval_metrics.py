"""Metrics on hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from eval import metrics
from graphpos.drive import Channel, Window
from graphpos.estimate import Estimate
from graphpos.errors import MissingChannelError


def test_position_stats_hand_computed():
    # errors (3,4), (0,0), (-6,8): distances 5, 0, 10
    s = metrics.position_error_stats([3.0, 0.0, -6.0], [4.0, 0.0, 8.0])
    assert s["n"] == 3
    assert s["max_m"] == 10.0
    assert s["mean_m"] == pytest.approx(5.0)
    assert s["median_m"] == 5.0
    assert s["rms_m"] == pytest.approx(math.sqrt(125 / 3))
    assert s["drms2_m"] == pytest.approx(2 * math.sqrt(125 / 3))
    assert s["p95_m"] == pytest.approx(5 + 0.9 * 5)  # linear between 5 and 10 at rank 1.9
    assert s["east_mean_m"] == pytest.approx(-1.0)
    assert s["east_std_m"] == pytest.approx(math.sqrt((16 + 1 + 25) / 3))
    assert s["north_mean_m"] == pytest.approx(4.0)
    assert s["north_std_m"] == pytest.approx(math.sqrt((0 + 16 + 16) / 3))


def test_position_stats_empty_is_nan():
    s = metrics.position_error_stats([], [])
    assert s["n"] == 0 and math.isnan(s["rms_m"])


def test_scalar_stats():
    s = metrics.scalar_error_stats(np.array([1.0, -1.0, 2.0, np.nan]), "mps")
    assert s["n"] == 3
    assert s["mean_mps"] == pytest.approx(2 / 3)
    assert s["rms_mps"] == pytest.approx(math.sqrt(2))
    assert s["max_abs_mps"] == 2.0


def test_nees_hand_computed():
    err = np.array([[1.0, 0.0], [1.0, 1.0], [1.0, 1.0]])
    cov = np.array([np.diag([4.0, 1.0]), np.diag([1.0, 1.0]), [[2.0, 1.0], [1.0, 2.0]]])
    # 1/4 ; 2 ; [1 1] inv([[2,1],[1,2]]) [1 1]^T = (2 - 2 + 2)/3 = 2/3
    assert metrics.nees(err, cov) == pytest.approx([0.25, 2.0, 2 / 3])
    bad = metrics.nees(err[:1], np.zeros((1, 2, 2)))
    assert np.isnan(bad).all()


def test_anees_band_matches_chi2():
    lo, hi = metrics.anees_band(50)
    assert lo == pytest.approx(stats.chi2.ppf(0.025, 100) / 50)
    assert hi == pytest.approx(stats.chi2.ppf(0.975, 100) / 50)
    assert lo < 2 < hi


def test_nees_of_a_consistent_estimator_lands_in_its_band():
    rng = np.random.default_rng(3)
    n = 400
    # random SPD covariances, errors drawn from them
    a = rng.normal(size=(n, 2, 2))
    cov = a @ np.transpose(a, (0, 2, 1)) + 0.1 * np.eye(2)
    err = np.einsum("kij,kj->ki", np.linalg.cholesky(cov), rng.normal(size=(n, 2)))
    s = metrics.nees_stats(err, cov)
    assert s["in_band"], s
    assert 0.92 < s["frac_below_95"] < 0.98
    # an overconfident one (covariance 4x too small) does not
    assert not metrics.nees_stats(err, cov / 4)["in_band"]


def test_output_rate():
    assert metrics.output_rate_hz(np.arange(0, 5, 0.1)) == pytest.approx(10.0)
    assert math.isnan(metrics.output_rate_hz(np.array([1.0])))


def test_interpolation_of_yaw_goes_the_short_way():
    t = np.array([0.0, 1.0])
    truth = Channel("truth", {"t_s": t, "east_m": [0, 2], "north_m": [0, 0], "v_east_mps": [2, 2],
                              "v_north_mps": [0, 0], "yaw_rad": [np.pi - 0.1, -np.pi + 0.1]})
    at = metrics.interpolate_truth(truth, np.array([-1.0, 0.5, 0.75, 2.0]))
    assert at.mask.tolist() == [False, True, True, False]
    assert at.east_m == pytest.approx([1.0, 1.5])
    assert abs(metrics.wrap_angle(at.yaw_rad[0] - np.pi)) == pytest.approx(0.0, abs=1e-12)
    assert metrics.wrap_angle(at.yaw_rad[1] - (np.pi + 0.05)) == pytest.approx(0.0, abs=1e-12)


def test_window_slicing_unites_same_label():
    t = np.arange(10.0)
    masks = metrics.window_masks(t, [Window("zone:a", 1, 2), Window("zone:a", 7, 8), Window("in_tunnel", 3, 5)])
    assert masks[metrics.WHOLE].all()
    assert np.flatnonzero(masks["zone:a"]).tolist() == [1, 2, 7, 8]
    assert np.flatnonzero(masks["in_tunnel"]).tolist() == [3, 4, 5]


def test_evaluate_estimate_per_window(drive):
    # estimate at 1 Hz: 1 m east of truth inside the tunnel window [2, 6], 3 m north elsewhere
    t = np.arange(0.0, 11.0)  # t=10 inside truth span, nothing outside
    inside = (t >= 2) & (t <= 6)
    est = Estimate("x", t, 2.0 * t + np.where(inside, 1.0, 0.0), np.where(inside, 0.0, 3.0),
                   v_east_mps=np.full(t.size, 2.5), v_north_mps=np.zeros(t.size),
                   cov_en_m2=np.tile(np.eye(2), (t.size, 1, 1)), rate_hz=1.0, wall_time_s=0.5)
    r = metrics.evaluate_estimate(drive, est)
    tun = r["windows"]["in_tunnel"]["position"]
    assert tun["n"] == 5 and tun["rms_m"] == pytest.approx(1.0) and tun["east_mean_m"] == pytest.approx(1.0)
    whole = r["windows"][metrics.WHOLE]["position"]
    assert whole["n"] == 11 and whole["max_m"] == pytest.approx(3.0)
    assert whole["rms_m"] == pytest.approx(math.sqrt((5 * 1 + 6 * 9) / 11))
    zone = r["windows"]["zone:a"]["position"]
    assert zone["n"] == 4 and zone["mean_m"] == pytest.approx(3.0)
    # speed error 0.5 m/s, raw wheel error 0.1 m/s (the fixture's wheel bias)
    assert r["windows"][metrics.WHOLE]["speed"]["mean_mps"] == pytest.approx(0.5)
    assert r["windows"][metrics.WHOLE]["wheel_speed"]["mean_mps"] == pytest.approx(0.1)
    assert r["windows"]["in_tunnel"]["nees"]["anees"] == pytest.approx(1.0)
    assert r["output_rate_hz"] == pytest.approx(1.0)
    assert r["velocity_provided"] and r["covariance_provided"]
    assert r["real_time_factor"] == pytest.approx(0.5 / 10.0)
    assert r["unscored_outputs"] == 0


def test_held_to_end_repeats_the_last_output_until_the_end(drive):
    """An estimator silent after 4 s (of the truth's 10) is scored with its last output held, at its own interval."""
    t = np.arange(0.0, 5.0)
    est = Estimate("x", t, 2.0 * t, np.zeros(5), cov_en_m2=np.tile(np.eye(2), (5, 1, 1)))
    held = metrics.held_to_end(est, 10.0)
    assert held.t_s.tolist() == list(range(11)) and np.all(held.east_m[5:] == 8.0) and held.cov_en_m2.shape == (11, 2, 2)
    whole = metrics.evaluate_estimate(drive, held)["windows"][metrics.WHOLE]["position"]
    # the truth drives on east at 2 m/s: 2, 4, ... 12 m off at 5 ... 10 s
    assert whole["max_m"] == pytest.approx(12.0)
    assert whole["rms_m"] == pytest.approx(math.sqrt(sum((2.0 * k) ** 2 for k in range(1, 7)) / 11))
    assert metrics.held_to_end(held, 10.4) is held  # its last output within one interval of the end
    one = Estimate("x", np.array([1.0]), np.array([2.0]), np.zeros(1))
    assert metrics.held_to_end(one, 10.0) is one


def test_unscored_epochs_outside_truth(drive):
    t = np.array([-1.0, 0.0, 5.0, 20.0])
    est = Estimate("x", t, 2 * t, np.zeros(4))
    r = metrics.evaluate_estimate(drive, est)
    assert r["unscored_outputs"] == 2
    assert r["windows"][metrics.WHOLE]["position"]["rms_m"] == pytest.approx(0.0)
    assert r["windows"][metrics.WHOLE]["speed"] is None and r["windows"][metrics.WHOLE]["nees"] is None


def test_drive_without_truth_is_refused(drive):
    bare = drive.replace(channels={"wheel": drive.wheel})
    with pytest.raises(MissingChannelError, match="evaluate needs truth"):
        metrics.evaluate_estimate(bare, Estimate("x", [0.0], [0.0], [0.0]))
