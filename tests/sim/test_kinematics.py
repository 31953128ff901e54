"""The truth is one trajectory: body accelerations and yaw rate integrate to the track."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.sim import SCENARIOS, simulate


def integrate_track(truth):
    """Dead-reckon the truth's own body accelerations and yaw rate (trapezoid)."""
    t = truth.t_s
    dt = np.diff(t)

    def cumtrapz(y):
        return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * dt)])

    speed0 = np.hypot(truth.v_east_mps[0], truth.v_north_mps[0])
    speed = speed0 + cumtrapz(truth.accel_x_mps2)
    yaw = truth.yaw_rad[0] + cumtrapz(truth.yaw_rate_radps)
    east = truth.east_m[0] + cumtrapz(speed * np.cos(yaw))
    north = truth.north_m[0] + cumtrapz(speed * np.sin(yaw))
    return speed, yaw, east, north


def check_consistent(drive, pos_tol_m, yaw_tol_rad):
    truth = drive.truth
    speed, yaw, east, north = integrate_track(truth)
    true_speed = np.hypot(truth.v_east_mps, truth.v_north_mps)
    assert np.abs(speed - true_speed).max() < 0.01
    assert np.abs(yaw - truth.yaw_rad).max() < yaw_tol_rad
    assert np.hypot(east - truth.east_m, north - truth.north_m).max() < pos_tol_m
    # velocity is along the heading (no sideslip) and is the derivative of position
    assert np.allclose(np.arctan2(truth.v_north_mps, truth.v_east_mps), np.angle(np.exp(1j * truth.yaw_rad)), atol=1e-9)
    ve = np.gradient(truth.east_m, truth.t_s)
    vn = np.gradient(truth.north_m, truth.t_s)
    assert np.abs(ve - truth.v_east_mps)[1:-1].max() < 0.02
    assert np.abs(vn - truth.v_north_mps)[1:-1].max() < 0.02
    # lateral acceleration is centripetal: a_y = v * yaw rate
    assert np.allclose(truth.accel_y_mps2, true_speed * truth.yaw_rate_radps, atol=1e-9)


@pytest.mark.parametrize("name", list(SCENARIOS))
@pytest.mark.parametrize("pattern", ["accel", "decel"])
def test_one_pass_integrates_to_the_track(name, pattern):
    """Tolerance: 15 cm over one pass (up to 1 km). Curvature steps (a bend's
    start and end) fall between two 100 Hz samples, so the trapezoid rule
    misses up to half a sample of the step: ~1e-3 rad of heading, carried
    over the rest of the pass."""
    check_consistent(simulate(name, pattern, seed=0), pos_tol_m=0.15, yaw_tol_rad=2e-3)


@pytest.mark.parametrize("pattern", ["lane-change-straight", "lane-change-curve", "accel-variable", "decel-variable"])
def test_curved_patterns_integrate_to_the_track(pattern):
    check_consistent(simulate("paper-imm", pattern, seed=0), pos_tol_m=0.05, yaw_tol_rad=2e-3)


def test_ten_minutes_out_and_back_integrate_to_the_track():
    """Tolerance: 0.5 m after 10 minutes of open-loop integration through
    U-turns (their curvature flips between two 100 Hz samples)."""
    drive = simulate("paper-comprehensive", "lane-change-curve", seed=0, duration_s=600)
    check_consistent(drive, pos_tol_m=0.5, yaw_tol_rad=0.01)


def test_path_closes_after_each_lap():
    drive = simulate("paper-imm", "accel", seed=0, duration_s=1.0)
    lap = drive.params["realised"]["lap_duration_s"]
    long = simulate("paper-imm", "accel", seed=0, duration_s=2 * lap + 1)
    t = long.truth.t_s
    for k in (1, 2):
        i = np.argmin(np.abs(t - k * lap))
        j = np.argmin(np.abs(t - 0.0))
        assert np.hypot(long.truth.east_m[i] - long.truth.east_m[j], long.truth.north_m[i] - long.truth.north_m[j]) < 0.05
        # two left U-turns per lap: yaw is unwrapped and grows by 2 pi
        assert long.truth.yaw_rad[i] - long.truth.yaw_rad[j] == pytest.approx(2 * np.pi * k, abs=0.01)


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_long_drives_are_continuous(name):
    """No jump where passes and U-turns join, for every pattern. (Tolerance
    1 mm: the path's arc length is integrated on a 2 cm grid, which is off by
    a fraction of a millimetre where the curvature steps.)"""
    for pattern in SCENARIOS[name].patterns:
        first = simulate(name, pattern, seed=0, duration_s=1.0).params["realised"]
        drive = simulate(name, pattern, seed=0, duration_s=first["lap_duration_s"] * 1.2)
        truth = drive.truth
        step = np.hypot(np.diff(truth.east_m), np.diff(truth.north_m))
        speed = np.hypot(truth.v_east_mps, truth.v_north_mps)
        assert np.all(step <= 0.5 * (speed[1:] + speed[:-1]) * 0.01 + 1e-3), pattern
        assert np.abs(np.diff(truth.yaw_rad)).max() < 0.01, pattern
