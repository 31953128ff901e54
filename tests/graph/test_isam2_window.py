"""graph-isam2's windowed iSAM2 (issue 19 item 4): a bounded tree, the whole drive still smoothed and learnt on."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest
from graph_drives import synthetic_drive

from graphpos.graph import ESTIMATORS
from graphpos.graph.config import GraphConfig
from graphpos.sim import simulate

WINDOW_S = 10.0


@pytest.fixture(scope="module")
def drive():
    return simulate("paper-straight", seed=0).without_truth()


def _gap_m(a, b) -> float:
    assert np.array_equal(a.t_s, b.t_s)
    return float(np.max(np.hypot(a.east_m - b.east_m, a.north_m - b.north_m)))


def _run_online(drive, config):
    est = ESTIMATORS["graph-isam2"](config)
    prepared = est.prepare(drive)
    est.start(prepared)
    for m in prepared.measurements(est.channels_used(prepared)):
        est.process(m)
    return est, est.finish()


def test_the_isam2_holds_only_its_window(drive):
    """A 76 s drive with a 10 s window: the iSAM2 ends with at most the window's keyframes (and those of one
    period of batched marginalisation), and the causal output is graph-fixed-lag's with the same lag."""
    config = GraphConfig(isam2_window_s=WINDOW_S, fixed_lag_s=WINDOW_S, learn_online=False, output_covariance=False)
    est, out = _run_online(drive, config)
    theta = est.smoother.isam.getLinearizationPoint()
    poses = [k for k in theta.keys() if chr(gtsam.Symbol(k).chr()) == "x"]
    assert out.diagnostics["keyframes"] > 700
    assert 0 < len(poses) <= (WINDOW_S + est.smoother.marginalise_every_s) * config.keyframe_rate_hz + 1
    # its estimate still has every keyframe: the marginalised ones as they were when they left
    held = est.smoother.estimate()
    assert all(held.exists(est.model.pose_key(k)) for k in range(out.diagnostics["keyframes"]))
    fixed_lag = ESTIMATORS["graph-fixed-lag"](config).run(drive)
    assert _gap_m(out, fixed_lag) < 1e-6


def test_final_smoothing_is_over_the_whole_drive_whatever_the_window(drive):
    """``final``: the builder's history, not the window, is solved: a 10 s window gives the smoothed drive of a
    window longer than the drive, positions and covariances alike (to Levenberg-Marquardt's tolerance: the two
    solves start from different values, the window's estimate and the causal states before it)."""
    config = GraphConfig(final=True, learn_online=False)
    whole = ESTIMATORS["graph-isam2"](config).run(drive)
    windowed = ESTIMATORS["graph-isam2"](dataclasses.replace(config, isam2_window_s=WINDOW_S)).run(drive)
    assert _gap_m(whole, windowed) < 1e-3
    np.testing.assert_allclose(windowed.cov_en_m2, whole.cov_en_m2, rtol=1e-2, atol=1e-5)


def test_learning_rebuilds_the_ranges_left_in_the_window():
    """Online learning solves the whole track so far (marginalised keyframes included) and rebuilds the ranges
    still in the window (reported ranges 5 % long, no range model: graph-isam2 learns one); the causal output
    stays close to that of a window longer than the drive."""
    drive = synthetic_drive(70, seed=3, turn_radps=0.05, range_scale=1.05).without_truth()
    est, windowed = _run_online(drive, GraphConfig(isam2_window_s=WINDOW_S, output_covariance=False))
    whole = ESTIMATORS["graph-isam2"](GraphConfig(output_covariance=False)).run(drive)
    learnt = windowed.diagnostics["online_calibration"]
    assert len(learnt) >= 2
    assert all(entry["ranges_rebuilt"] > 0 for entry in learnt)
    assert learnt[-1]["keyframe"] * est.builder.period_s > 2 * WINDOW_S
    assert learnt[-1]["ranges_rebuilt"] < 0.6 * len(est.builder.range_records)
    assert _gap_m(windowed, whole) < 0.3


def test_ranges_rebuilt_in_chunks_are_each_swapped_once(monkeypatch):
    """A learning swaps the window's range factors a few per iSAM2 update (here 7): afterwards the iSAM2 holds
    exactly one range factor per range record it has keys for, and the causal output is that of one swap."""
    import collections

    from graphpos.graph import estimators

    drive = synthetic_drive(70, seed=3, turn_radps=0.05, range_scale=1.05).without_truth()
    config = GraphConfig(isam2_window_s=WINDOW_S, output_covariance=False)
    _, at_once = _run_online(drive, config)
    monkeypatch.setattr(estimators, "REBUILD_CHUNK_FACTORS", 7)
    est, chunked = _run_online(drive, config)
    assert max(entry["ranges_rebuilt"] for entry in chunked.diagnostics["online_calibration"]) > 7
    isam = est.smoother.isam
    factors, theta = isam.getFactorsUnsafe(), isam.getLinearizationPoint()
    held = collections.Counter(tuple(factors.at(i).keys()) for i in range(factors.size())
                               if factors.exists(i) and isinstance(factors.at(i), (gtsam.RangeFactor2D, gtsam.RangeFactor3D)))
    records = collections.Counter((est.model.pose_key(r.keyframe), r.landmark_key) for r in est.builder.range_records
                                  if theta.exists(est.model.pose_key(r.keyframe)) and theta.exists(r.landmark_key))
    assert held == records and sum(held.values()) > 0
    assert _gap_m(chunked, at_once) < 0.05


def test_the_window_bookkeeping_matches_the_isam2_when_keys_are_stamped_again():
    """The keys the window expects to hold are exactly those in its iSAM2, update after update, when a
    landmark is stamped again at every update (it must stay) and keyframes leave in batches."""
    from gtsam.symbol_shorthand import L, X

    from graphpos.graph.smoothers import WindowedIsam2Smoother

    window = WindowedIsam2Smoother("planar", window_s=2.0)
    odometry = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.01]))
    rng = np.random.default_rng(5)
    for k in range(80):
        t_s = 0.1 * k
        factors, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(k), gtsam.Pose2(0.5 * t_s, 0.0, 0.0))
        if k == 0:
            factors.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), odometry))
            factors.add(gtsam.PriorFactorPoint2(L(1), np.array([2.0, 3.0]), gtsam.noiseModel.Isotropic.Sigma(2, 0.01)))
            values.insert(L(1), np.array([2.0, 3.0]))
        else:
            factors.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(0.05, 0.0, 0.0), odometry))
        distance = float(np.hypot(0.5 * t_s - 2.0, 3.0))
        factors.add(gtsam.RangeFactor2D(X(k), L(1), distance + 0.01 * rng.standard_normal(), gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
        window.update(factors, values, {X(k): t_s, L(1): t_s})
        held = set(window.isam.getLinearizationPoint().keys())
        assert set(window._stamps) == held, k
        assert set().union(*window._by_stamp.values()) == held, k
    assert L(1) in held and X(0) not in held and window.estimate().exists(X(0))
