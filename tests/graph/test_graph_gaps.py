"""Gaps and late readings (issue 14, item 3): determinate across any gap, a fresh start after it.

Drives: the synthetic drive with a pause in every sensor (30 s, 10 min: the
recording stops while the vehicle stands), every sensor lost while the
vehicle drives on, the odometry lost while ranges and compass go on, a
pause shorter than ``max_odometry_gap_s`` (held), and RFID readings
arriving 500 s late. Every graph estimator in both parameterisations, and
every filter that takes the drive, runs on ``drive.without_truth()``; the
scores use the truth afterwards.

Graphs: no exception, finite outputs and covariances, no keyframe
extrapolated into the gap, the gap and the restart in the diagnostics, a
sane error before and after it. Readings later than ``max_delay_s`` are
dropped and counted; graph-batch, offline, uses every reading whenever it
arrived. Filters: no exception, no NaN; those that dead-reckon from a
start end their track at the gap and start again after it too.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from graph_drives import errors, late_rfid, paused, rms, run, synthetic_drive, truth_at, without_span
from hypothesis import given, settings
from hypothesis import strategies as st

from filters import ESTIMATORS as FILTERS
from graphpos.drive import Drive
from graphpos.errors import MissingChannelError
from graphpos.graph import ESTIMATORS as GRAPHS
from graphpos.graph import ODOMETRY_ESTIMATORS
from graphpos.graph.config import GraphConfig

GRAPH_KEYS = tuple(f"{name}/{p}" for name in sorted(ODOMETRY_ESTIMATORS) for p in ("planar", "inertial"))
#: Where the gaps begin, s (after the turn has begun, a third into the drive).
GAP_AT_S = 12.0
MAX_GAP_S = GraphConfig().max_odometry_gap_s


@lru_cache(maxsize=None)
def base() -> Drive:
    return synthetic_drive(30, seed=21, turn_radps=0.05)


@lru_cache(maxsize=None)
def clean_run(key: str):
    return run(key, base())


def filters_for(drive: Drive) -> list[str]:
    """The filters that take the drive (those lacking a channel refuse it, as they should)."""
    names = []
    for name, cls in FILTERS.items():
        try:
            cls().check(drive)
        except MissingChannelError:
            continue
        names.append(name)
    return names


def nees(drive: Drive, est) -> np.ndarray:
    err = est.position - truth_at(drive, est.t_s)
    return np.einsum("ni,ni->n", err, np.linalg.solve(est.cov_en_m2, err[..., None])[..., 0])


def check_restarted(drive: Drive, est, from_s: float, to_s: float, held_s: float = 0.0, rms_m: float = 0.5) -> None:
    """Finite, one gap listed from ``from_s`` to ``to_s`` with a restart, no keyframe more than ``held_s`` into the gap,
    sane errors before the gap and once restarted, honest covariances."""
    assert np.all(np.isfinite(est.position)) and np.all(np.isfinite(est.cov_en_m2))
    (gap,) = est.diagnostics["odometry_gaps"]
    assert gap["from_s"] == pytest.approx(from_s, abs=0.02) and gap["to_s"] == pytest.approx(to_s, abs=0.02), gap
    assert gap["restart"] is not None and to_s <= gap["restart"]["t_s"] <= to_s + 6.0, gap
    in_gap = (est.t_s > from_s + held_s + 0.051) & (est.t_s < to_s - 1e-6)
    assert not in_gap.any(), est.t_s[in_gap][:5]
    e = errors(drive, est)
    t = est.t_s[est.t_s <= drive.truth.t_s[-1]]
    before, after = t < from_s - 0.5, t > gap["restart"]["t_s"] + 2.0
    assert rms(e[before]) < 0.5 and rms(e[after]) < rms_m and e[after].max() < 1.5, (rms(e[before]), rms(e[after]), e[after].max())
    assert after.sum() > 50
    assert np.mean(nees(drive, est)[est.t_s > gap["restart"]["t_s"]]) < 6.0  # 2 on average: not over-confident after the restart


@pytest.mark.parametrize("pause_s", [30.0, 600.0])
@pytest.mark.parametrize("key", GRAPH_KEYS)
def test_every_sensor_paused(key, pause_s):
    drive = paused(base(), GAP_AT_S, pause_s)
    est = run(key, drive)
    last_s = drive.imu.t_s[drive.imu.t_s < GAP_AT_S][-1]
    check_restarted(drive, est, last_s, GAP_AT_S + pause_s)
    assert est.diagnostics["without_odometry"] == {}


@pytest.mark.parametrize("key", GRAPH_KEYS)
def test_every_sensor_lost_while_the_vehicle_drives_on(key):
    drive = without_span(base(), GAP_AT_S, GAP_AT_S + 5.0)  # 25 m unobserved
    est = run(key, drive)
    check_restarted(drive, est, GAP_AT_S - 0.01, GAP_AT_S + 5.0)


@pytest.mark.parametrize("key", GRAPH_KEYS)
def test_odometry_lost_while_ranges_and_compass_go_on(key):
    drive = without_span(base(), GAP_AT_S, GAP_AT_S + 6.0, ("imu", "wheel"))
    est = run(key, drive)
    # readings during the gap close keyframes on the held odometry for up to max_odometry_gap_s, no further
    check_restarted(drive, est, GAP_AT_S - 0.01, GAP_AT_S + 6.0, held_s=MAX_GAP_S)
    # the readings nearest no keyframe of either track are dropped and counted
    last_s = est.t_s[est.t_s < GAP_AT_S + 6.0].max()
    beyond = {c: int(np.sum((drive.channels[c].t_s > last_s + 0.05) & (drive.channels[c].t_s < GAP_AT_S + 6.0))) for c in ("rfid", "compass")}
    assert est.diagnostics["without_odometry"] == beyond


@pytest.mark.parametrize("key", GRAPH_KEYS)
def test_odometry_pause_shorter_than_the_hold_is_bridged(key):
    drive = without_span(base(), GAP_AT_S, GAP_AT_S + 0.8 * MAX_GAP_S, ("imu", "wheel"))
    est = run(key, drive)
    assert est.diagnostics["odometry_gaps"] == [] and np.all(np.isfinite(est.position))
    assert rms(errors(drive, est)) < rms(errors(base(), clean_run(key))) + 0.1


@settings(max_examples=6, deadline=None)
@given(at_s=st.floats(4.0, 22.0), pause_s=st.floats(MAX_GAP_S + 0.2, 3600.0))
def test_any_pause_in_every_sensor(at_s, pause_s):
    drive = paused(base(), at_s, pause_s)
    est = run("graph-isam2/inertial", drive)
    assert np.all(np.isfinite(est.position)) and np.all(np.isfinite(est.cov_en_m2))
    (gap,) = est.diagnostics["odometry_gaps"]
    assert gap["to_s"] == pytest.approx(drive.imu.t_s[drive.imu.t_s >= at_s][0])
    restarted = gap["restart"]
    if restarted is not None:  # too little drive left after the pause may leave it unstarted: no output then
        after = est.t_s[est.t_s <= drive.truth.t_s[-1]] > restarted["t_s"] + 2.0
        assert rms(errors(drive, est)[after]) < 0.6


@pytest.mark.parametrize("key", GRAPH_KEYS)
def test_readings_500_s_late(key):
    drive, late = late_rfid(base(), 500.0, 0.3)
    assert late.sum() > 20
    est = run(key, drive)
    assert np.all(np.isfinite(est.position))
    assert est.t_s.max() <= drive.imu.t_s[-1] + 0.051  # no keyframes conjured up to the late arrivals
    assert est.diagnostics["odometry_gaps"] == []  # the odometry ended; it has no gap
    if key.startswith("graph-batch"):
        # offline: every reading is used, whenever it arrived: the same solve as with none late
        assert est.diagnostics["late_dropped"] == {} and est.diagnostics["late_attached"] == {}
        np.testing.assert_allclose(est.position, clean_run(key).position, atol=1e-9)
    else:
        assert est.diagnostics["late_dropped"] == {"rfid": int(late.sum())}
        assert rms(errors(drive, est)) < rms(errors(base(), clean_run(key))) + 0.15


@pytest.mark.parametrize("key", [k for k in GRAPH_KEYS if not k.startswith("graph-batch")])
def test_every_reading_late_never_starts_online(key):
    drive, late = late_rfid(base(), 500.0, 1.0)
    est = run(key, drive)
    assert len(est) == 0 and "not_started" in est.diagnostics
    assert est.diagnostics["late_dropped"] == {"rfid": len(drive.rfid)}


@lru_cache(maxsize=None)
def awkward(case: str) -> Drive:
    return {
        "paused-600": lambda: paused(base(), GAP_AT_S, 600.0),
        "all-lost": lambda: without_span(base(), GAP_AT_S, GAP_AT_S + 5.0),
        "odometry-lost": lambda: without_span(base(), GAP_AT_S, GAP_AT_S + 6.0, ("imu", "wheel")),
        "late-500": lambda: late_rfid(base(), 500.0, 0.3)[0],
    }[case]()


@pytest.mark.parametrize("case", ["paused-600", "all-lost", "odometry-lost", "late-500"])
def test_filters_take_the_same_drives(case):
    """No exception, no NaN; a filter that needs a start and dead-reckons ends its track at the gap and starts again after it."""
    drive = awkward(case)
    for name in filters_for(drive):
        est = run(name, drive)
        assert len(est) > 0 and np.all(np.isfinite(est.position)), name
        if est.cov_en_m2 is not None:
            assert np.all(np.isfinite(est.cov_en_m2)), name
        dead_reckons = FILTERS[name].needs_start and {"imu", "wheel"} & set(FILTERS[name]().channels_used(drive))
        if case == "late-500" or not dead_reckons:
            assert est.diagnostics.get("odometry_gaps", []) == [], name
            continue
        (gap,) = est.diagnostics["odometry_gaps"]
        assert gap["restart"] is not None, name
        t = est.t_s[est.t_s <= drive.truth.t_s[-1]]
        assert not np.any((t > gap["from_s"] + MAX_GAP_S + 0.1) & (t < gap["to_s"])), name
        assert rms(errors(drive, est)[t > gap["restart"]["t_s"] + 2.0]) < 1.0, name


@pytest.mark.parametrize("name", ["fusion-ekf", "fukf", "ekf-ca", "dr"])
def test_filter_run_is_its_online_loop_across_a_gap(name):
    drive = awkward("odometry-lost")
    fast, online = run(name, drive), run(name, drive, spoil=lambda _, m: m)
    np.testing.assert_allclose(fast.position, online.position, atol=1e-9)
    assert fast.diagnostics["odometry_gaps"] == online.diagnostics["odometry_gaps"]


@pytest.mark.parametrize("key", [*GRAPH_KEYS, "fusion-ekf", "fukf", "dr"])
def test_odometry_gap_before_the_start(key):
    """A gap while the start is still being sought: the track before it is forgotten, the start found after it."""
    drive = without_span(synthetic_drive(30, seed=22, turn_radps=0.05, absolute_from_s=10.0), 4.0, 7.0, ("imu", "wheel"))
    est = run(key, drive)
    assert np.all(np.isfinite(est.position)) and len(est) > 0
    (gap,) = est.diagnostics["odometry_gaps"]
    assert gap["to_s"] == pytest.approx(7.0) and gap["restart"] is None  # the drive's start comes after the gap
    assert est.diagnostics["start"]["t_s"] >= 10.0 and est.t_s[0] >= 7.0
    e = errors(drive, est)
    assert rms(e) < (1.0 if key == "dr" else 0.5), rms(e)
