"""Start-up on awkward drives (issue 13, item 3): every estimator that needs a start, whatever arrives first.

The three graph estimators (both parameterisations) and the filters that
need a start state (``needs_start``: fusion-ekf, fukf, two-level-ekf, dr
and, where the drive has accelerometers and a compass, song2014's ekf-ca,
stekf-ca and imm-stekf) run on synthetic drives that begin badly: odometry
only, a single range, a single beacon, standing still, one tag in view at a
time, a wrong user start pose, tags on one wall only, ranges before
odometry. Estimators get ``drive.without_truth()``; scores use the full drive.

On every drive: no traceback (no IndeterminantLinearSystem / EstimationError),
no silent (0, 0), and either no output with the not-started diagnostic, or
output from the start on with a sane error. The causal estimators output
nothing before their start; graph-batch, a smoother, gives the whole drive
once it has started (the held track smoothed back from the start).

Known failures are marked ``xfail(strict=True)`` with the cause; see the
``BUG_*`` reasons below.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest
from graph_drives import errors, rms, run, synthetic_drive, truth_at

from graphpos.drive import Drive
from graphpos.graph import ESTIMATORS as GRAPHS
from graphpos.graph import ODOMETRY_ESTIMATORS
from graphpos.ignition import StartPose, between_walls

SONG2014 = ("ekf-ca", "stekf-ca", "imm-stekf")
SONG2016 = ("fusion-ekf", "fukf", "two-level-ekf", "dr")
GRAPH_KEYS = tuple(f"{name}/{p}" for name in sorted(ODOMETRY_ESTIMATORS) for p in ("planar", "inertial"))

# -- known failures (not fixed here: graphpos/graph/ and filters/ are being changed elsewhere) ----------------
BUG_TWO_LEVEL_ONE_TAG = (
    "two-level-ekf with one tag per scan: level 1 (the RFID-EKF's position random walk) cannot follow the "
    "vehicle from single ranges, gates most of them and lags; level 2 takes its lagging positions as fixes "
    "-> metres off with a sub-metre covariance (NEES >> 2) (fix, checked by monkeypatching: move level 1 on by "
    "level 2's velocity before each scan; 3.8 m -> 0.15 m max here, a deviation from song2016b to document)"
)
BUG_LMS_MIRROR = (
    "song2014 filters hearing tags on one wall: the LMS-federated positioner solves each scan alone (Gauss-Newton "
    "from the tags' centroid when its track is lost) and lands on the mirror image across the wall; the fusion "
    "filter takes the fix without a gate -> metres off, confidently (fix, checked by monkeypatching: seed the "
    "positioner with the fusion filter's position when its own track is lost: 8.7 m -> 0.7 m max here; or gate the fix)"
)
def xfail(key: str, reason: str):
    return pytest.param(key, marks=pytest.mark.xfail(strict=True, reason=reason))


def keys_for(drive: Drive, known: dict[str, str] | None = None) -> list:
    """Estimator keys that can run on ``drive`` (channels), known failures marked."""
    known = known or {}
    out = [k for k in GRAPH_KEYS if drive.has_accelerometers or not k.endswith("/inertial")]
    out += [n for n in SONG2016 if n == "dr" or drive.has("rfid")]
    if drive.has("compass") and drive.has_accelerometers and drive.has("rfid"):
        out += list(SONG2014)
    return [xfail(k, known[k]) if k in known else k for k in out]


def without(drive: Drive, *channels: str) -> Drive:
    return drive.replace(channels={k: v for k, v in drive.channels.items() if k not in channels})


def start_time(est) -> float | None:
    start = est.diagnostics.get("start")
    return None if not start else start.get("t_s")


def check_output(key: str, drive: Drive, est) -> None:
    """What every run must satisfy: finite rows, no silent (0, 0), a start diagnostic, nothing before the start."""
    assert np.all(np.isfinite(est.position))
    if len(est) == 0:
        assert "not_started" in est.diagnostics and not est.diagnostics.get("start"), est.diagnostics
        return
    truth = truth_at(drive, est.t_s)
    zero = (est.east_m == 0.0) & (est.north_m == 0.0) & (np.hypot(*truth.T) > 1.0)
    assert not zero.any(), f"silent (0, 0) output at t = {est.t_s[zero][:3]}"
    assert est.diagnostics.get("start") is not None
    t0 = start_time(est)
    if t0 is not None and not key.startswith(("graph-batch", "graph-fixed-lag-smoothed")):  # smoothers also give the held track
        assert est.t_s[0] >= t0 - 0.05 - 1e-9, "output before the start"


def check_not_started(key: str, drive: Drive, est) -> None:
    check_output(key, drive, est)
    assert len(est) == 0, f"{key} started at {start_time(est)} s"


def check_sane(key: str, drive: Drive, est, rms_m: float = 0.5, max_m: float = 1.5, dr_rms_m: float = 1.0) -> np.ndarray:
    """Started, and a sane error after the start (dead reckoning: ``dr_rms_m``); returns the errors after the start."""
    check_output(key, drive, est)
    assert len(est) > 0, f"{key} never started: {est.diagnostics}"
    t0 = start_time(est)
    after = est.t_s[est.t_s <= drive.truth.t_s[-1]] >= (t0 if t0 is not None else -math.inf)
    e = errors(drive, est)[after]
    assert rms(e) < (dr_rms_m if key == "dr" else rms_m), (rms(e), e.max())
    if key != "dr":
        assert e.max() < max_m, (rms(e), e.max())
    return e


def nees(drive: Drive, est) -> np.ndarray:
    err = est.position - truth_at(drive, est.t_s)
    return np.einsum("ni,ni->n", err, np.linalg.solve(est.cov_en_m2, err[..., None])[..., 0])


# -- drives ------------------------------------------------------------------------------------------------------
@lru_cache(maxsize=None)
def odometry_first(compass: bool) -> Drive:
    """15 s (75 m) of wheel and IMU only, then tags and (with ``compass``) the compass; a gentle turn after 10 s."""
    return synthetic_drive(30, seed=21, turn_radps=0.05, absolute_from_s=15.0, compass=compass)


@lru_cache(maxsize=None)
def single_range(compass: bool) -> Drive:
    d = synthetic_drive(10, seed=22, turn_radps=0.1)
    d = d.replace(channels={**d.channels, "rfid": d.rfid.select(np.arange(len(d.rfid)) == 10)})
    return d if compass else without(d, "compass")


@lru_cache(maxsize=None)
def one_beacon(compass: bool) -> Drive:
    """One beacon (20, 10) in range all along: 3 s straight (mirror-ambiguous about the line of travel), then a turn."""
    d = synthetic_drive(11, seed=23, turn_radps=0.2, turn_after_s=3.0, beacons=[(20.0, 10.0, 0)], max_range_m=60.0)
    return d if compass else without(d, "compass")


STATIONARY_TAGS = [(-4.0, 3.0, 1), (4.0, 3.0, 1), (-4.0, -3.0, -1), (4.0, -3.0, -1)]


@lru_cache(maxsize=None)
def stationary(compass: bool, duration_s: float = 12.0) -> Drive:
    d = synthetic_drive(duration_s, seed=24, speed_mps=0.0, beacons=STATIONARY_TAGS)
    return d if compass else without(d, "compass")


@lru_cache(maxsize=None)
def staggered_tags() -> Drive:
    """One tag in view at a time: tags every 40 m on each wall, staggered by 20 m (one every 20 m), straight road."""
    tags = [(x, 3.0, 1) for x in range(0, 200, 40)] + [(x, -3.0, -1) for x in range(20, 200, 40)]
    return synthetic_drive(15, seed=25, beacons=tags)


@lru_cache(maxsize=None)
def one_wall(compass: bool = True, turn: bool = False) -> Drive:
    """Tags on the right wall only (north = -3 m), every 6 m; straight (6 s; 5 s without compass), or straight 4 s then a left turn."""
    if turn:
        return synthetic_drive(11, seed=27, walls=(-1,), turn_radps=0.2, turn_after_s=4.0)
    return synthetic_drive(6, seed=27, walls=(-1,)) if compass else without(synthetic_drive(5, seed=27, walls=(-1,)), "compass")


@lru_cache(maxsize=None)
def both_walls(compass: bool) -> Drive:
    d = synthetic_drive(12, seed=27)
    return d if compass else without(d, "compass")


@lru_cache(maxsize=None)
def both_walls_left_heard() -> Drive:
    """Tags mapped on both walls, but only the left wall's heard (the right ones failed)."""
    d = synthetic_drive(16, seed=27)
    right = d.tags.tag_id[d.tags.wall_side < 0]
    return d.replace(channels={**d.channels, "rfid": d.rfid.select(~np.isin(d.rfid.tag_id, right))})


@lru_cache(maxsize=None)
def ranges_before_odometry() -> Drive:
    """Ranges and compass from 0 s, wheel and IMU only from 3 s (the vehicle already moving at 5 m/s)."""
    d = synthetic_drive(20, seed=28, turn_radps=0.05)
    return d.replace(channels={**d.channels, "imu": d.imu.between(3.0, 99.0), "wheel": d.wheel.between(3.0, 99.0)})


@lru_cache(maxsize=None)
def late_ranges() -> Drive:
    return synthetic_drive(20, seed=28, turn_radps=0.05, rfid_latency_s=(0.5, 2.0))


def _side(points: np.ndarray, wall_a: np.ndarray, wall_b: np.ndarray) -> np.ndarray:
    """Sign of each point's side of the line through two wall tags."""
    ab = wall_b - wall_a
    rel = points - wall_a
    return np.sign(ab[0] * rel[:, 1] - ab[1] * rel[:, 0])


# -- (a) odometry first --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", keys_for(odometry_first(True)))
def test_odometry_only_for_15_s_then_ranges_and_compass(key):
    drive = odometry_first(True)
    est = run(key, drive)
    check_sane(key, drive, est)
    first_range_s = float(drive.rfid.t_s[0])
    assert first_range_s <= start_time(est) <= first_range_s + 3.0
    if key.startswith("graph-batch"):
        # the smoother also gives the 75 m before the start, dead-reckoned back from it
        assert est.t_s[0] == drive.start_s and errors(drive, est).max() < 2.5


@pytest.mark.parametrize("key", keys_for(odometry_first(False)))
def test_odometry_only_for_15_s_then_ranges_without_compass(key):
    drive = odometry_first(False)
    est = run(key, drive)
    check_sane(key, drive, est)
    first_range_s = float(drive.rfid.t_s[0])
    # heading from the direction of travel; dr waits for a 1-degree heading
    assert first_range_s <= start_time(est) <= first_range_s + (8.0 if key == "dr" else 3.0)
    if key.startswith("graph-batch"):
        assert errors(drive, est).max() < 2.5


# -- (b) a single range; a single beacon ------------------------------------------------------------------------


@pytest.mark.parametrize("key", keys_for(single_range(True)))
def test_a_single_range_never_starts(key):
    """One range in 10 s cannot fix three unknowns: no start, an empty estimate that says so."""
    drive = single_range(True)
    assert len(drive.rfid) == 1
    check_not_started(key, drive, run(key, drive))


@pytest.mark.parametrize("key", keys_for(single_range(False)))
def test_a_single_range_without_compass_never_starts(key):
    drive = single_range(False)
    check_not_started(key, drive, run(key, drive))


@pytest.mark.parametrize("key", keys_for(one_beacon(True)))
def test_one_beacon_with_compass_starts_once_the_turn_resolves_the_mirror(key):
    """Ranges to one beacon along a straight line fit the track and its mirror image about the line through
    the beacon equally well; the turn (with the compass) tells them apart, and the start comes then."""
    drive = one_beacon(True)
    est = run(key, drive)
    if key in SONG2014:
        # one tag per scan: their LMS positioner gives no fixes, they dead-reckon on, and their covariance says so
        check_sane(key, drive, est, rms_m=1.0, max_m=2.0)
        assert est.diagnostics["fixes_used"] == 0 and nees(drive, est).max() < 5.0
    else:
        check_sane(key, drive, est, rms_m=0.6)
    assert 3.0 <= start_time(est) <= 10.0


@pytest.mark.parametrize("key", keys_for(one_beacon(False)))
def test_one_beacon_without_compass_never_starts(key):
    """Without a heading reference, turning the whole track about the one beacon changes no range: never determinate."""
    drive = one_beacon(False)
    check_not_started(key, drive, run(key, drive))


# -- (c) standing still ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", keys_for(stationary(True)))
def test_stationary_with_compass_starts_and_is_consistent(key):
    drive = stationary(True)
    est = run(key, drive)
    check_sane(key, drive, est)
    assert start_time(est) <= 3.0
    q = nees(drive, est)  # not a wrong confident pose: the covariance covers the error
    assert q.mean() < 6.0 and q.max() < 25.0, (q.mean(), q.max())


@pytest.mark.parametrize("key", keys_for(stationary(False)))
def test_stationary_without_compass_waits_for_motion(key):
    """Heading is unobservable standing still without a compass: no start, so no wrong confident pose."""
    drive = stationary(False)
    check_not_started(key, drive, run(key, drive))


@pytest.mark.slow
@pytest.mark.parametrize("key", keys_for(stationary(False)))
def test_stationary_for_a_minute_without_compass_never_starts(key):
    """The wheel's noise (0.1 m/s) adds up to more than min_travel_m of "travel" standing still: still no start."""
    drive = stationary(False, 60.0)
    check_not_started(key, drive, run(key, drive))


@lru_cache(maxsize=None)
def standing_then_driving() -> Drive:
    """Standing for 6 s (wheel noise only), then driving away along both walls' tags; no compass."""
    return without(synthetic_drive(16, seed=29, stop=(0.0, 6.0)), "compass")


@pytest.mark.parametrize("key", keys_for(standing_then_driving()))
def test_standing_then_driving_without_compass_starts_once_moving(key):
    drive = standing_then_driving()
    est = run(key, drive)
    check_sane(key, drive, est)
    assert 6.0 <= start_time(est) <= (14.0 if key == "dr" else 10.0)


@lru_cache(maxsize=None)
def imu_and_ranges(compass: bool) -> Drive:
    """An IMU and wall tags, no wheel speed (an indoor UWB run), turning gently; with or without a compass."""
    return without(synthetic_drive(30, seed=31, turn_radps=0.05, compass=compass), "wheel")


@pytest.mark.parametrize("compass", [False, True])
@pytest.mark.parametrize("key", [k for k in GRAPH_KEYS if k.endswith("/inertial")])
def test_imu_and_ranges_without_wheel_speed(key, compass):
    """Without a compass the start has a free heading under a stiff gyro chain (Cholesky called it indeterminate,
    hence iSAM2's QR); without wheel speed nothing may hold the velocity at a standstill (causal RMS was 1.4 m)."""
    drive = imu_and_ranges(compass)
    est = run(key, drive)
    check_sane(key, drive, est, rms_m=0.3, max_m=1.2)
    assert start_time(est) <= 2.0


# -- (d) one beacon in view at a time -----------------------------------------------------------------------------
@pytest.mark.parametrize("key", keys_for(staggered_tags(), {"two-level-ekf": BUG_TWO_LEVEL_ONE_TAG}))
def test_one_tag_in_view_at_a_time(key):
    drive = staggered_tags()
    assert all(np.unique(drive.rfid.tag_id[drive.rfid.t_s == t]).size == 1 for t in np.unique(drive.rfid.t_s))
    est = run(key, drive)
    assert start_time(est) is not None and start_time(est) <= 6.0
    if key in SONG2014:
        # their LMS positioner needs several tags per scan: no fixes, dead reckoning, and a covariance that says so
        check_sane(key, drive, est, rms_m=2.0, max_m=4.0)
        assert est.diagnostics["fixes_used"] == 0 and nees(drive, est).max() < 5.0
    else:
        check_sane(key, drive, est)


@lru_cache(maxsize=None)
def sparse_one_wall() -> Drive:
    """One tag every 40 m on the left wall only (a tag heard for 3-4 s, then 4-5 s of none), a turn after 8 s."""
    return synthetic_drive(30, seed=25, tag_spacing_m=40.0, walls=(+1,), turn_radps=0.1, turn_after_s=8.0)


@pytest.mark.slow
@pytest.mark.parametrize("key", keys_for(sparse_one_wall()))
def test_one_tag_every_40_m_on_one_wall_with_a_turn(key):
    """Either no start (an empty estimate that says so) or, after the turn has resolved the mirror, a sane one."""
    drive = sparse_one_wall()
    est = run(key, drive)
    check_output(key, drive, est)
    if len(est):
        assert start_time(est) >= 8.0  # not before the turn: until then one wall's tags leave the mirror open
        check_sane(key, drive, est)


# -- (e) a wrong start pose from the user -------------------------------------------------------------------------
@lru_cache(maxsize=None)
def wrong_heading_drive() -> Drive:
    return synthetic_drive(15, seed=26, turn_radps=0.05)


@pytest.mark.parametrize("yaw_error_deg", [90.0, 180.0])
@pytest.mark.parametrize("key", keys_for(wrong_heading_drive()))
def test_wrong_user_heading_does_not_crash(key, yaw_error_deg):
    """A user start pose with the yaw off by 90 or 180 degrees (sigma 5): the user's mistake, no failure.

    How far off the causal estimates end up is not asserted (15 s drive
    with compass and tags: the song2016 filters recover within seconds,
    song2014's after up to 90 m excursions, iSAM2 / fixed-lag inertial by
    the end, planar stay about 6 m off); graph-batch, which solves the
    whole drive, must recover.
    """
    drive = wrong_heading_drive()
    pose = StartPose(0.0, 0.0, math.radians(yaw_error_deg), 1.0, math.radians(5.0))
    est = run(key, drive, initial_pose=pose)
    assert np.all(np.isfinite(est.position)) and len(est) > 0
    assert est.diagnostics["start"]["source"] == "user"
    assert est.t_s[0] - drive.start_s <= 0.1  # the user's pose starts it at once
    if key.startswith("graph-batch"):
        assert rms(errors(drive, est)) < 0.5  # the whole-drive solve overrides a wrong prior


def test_start_pose_stored_in_the_drive_is_used():
    drive = synthetic_drive(10, seed=26)
    stored = drive.replace(params={"initial_pose": StartPose(0.0, 0.0, 0.0).to_dict()})
    for key in ("graph-isam2/planar", "fusion-ekf"):
        est = run(key, stored)
        assert est.diagnostics["start"]["source"] == "user" and est.t_s[0] - drive.start_s <= 0.1


# -- (f) the wall mirror ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", keys_for(one_wall(True)))
def test_one_wall_straight_road_waits(key):
    """Tags on one wall along a straight road: the vehicle and its mirror image across the wall fit equally
    well (the compass cannot tell them apart either); nothing to drop them by: ignition waits, no mirror start."""
    drive = one_wall(True)
    check_not_started(key, drive, run(key, drive))


@pytest.mark.parametrize("key", [k if k in ("graph-isam2/planar", "graph-batch/inertial", "fusion-ekf", "dr") else pytest.param(k, marks=pytest.mark.slow)
                                 for k in keys_for(one_wall(False))])
def test_one_wall_straight_road_without_compass_waits(key):
    """(Eight trial headings per attempt without a compass make waiting dear: four estimators by default, all with -m slow.)"""
    drive = one_wall(False)
    check_not_started(key, drive, run(key, drive))


@pytest.mark.parametrize("key", keys_for(one_wall(turn=True)))
def test_one_wall_then_a_turn_starts_on_the_right_side(key):
    drive = one_wall(turn=True)
    est = run(key, drive)
    check_sane(key, drive, est)
    assert start_time(est) >= 4.0  # not before the turn
    # every output on the truth's side of the wall (of the two nearest wall tags)
    tags = np.column_stack([drive.tags.east_m, drive.tags.north_m])
    truth = truth_at(drive, est.t_s)
    for p, q in zip(est.position, truth):
        a, b = tags[np.argsort(np.hypot(*(tags - q).T))[:2]]
        assert _side(p[None], a, b)[0] == _side(q[None], a, b)[0]


@pytest.mark.parametrize("compass", [True, False])
@pytest.mark.parametrize("key", keys_for(both_walls(True)))
def test_both_walls_start_on_the_road(key, compass):
    drive = both_walls(compass)
    if key in SONG2014 and not compass:
        pytest.skip("song2014 needs a compass")
    est = run(key, drive)
    check_sane(key, drive, est)
    start = est.diagnostics["start"]
    assert start["t_s"] <= (8.0 if key == "dr" else 3.0)
    tags = np.column_stack([drive.tags.east_m, drive.tags.north_m])
    p = np.array([start["east_m"], start["north_m"]])
    assert between_walls(p, tags, drive.tags.wall_side) and abs(p[1]) < 3.0


@pytest.mark.parametrize("key", keys_for(both_walls_left_heard(), {k: BUG_LMS_MIRROR for k in SONG2014}))
def test_one_wall_heard_both_mapped_drops_the_mirror(key):
    """Only the left wall's tags are heard; the mirror across it lies behind that wall, outside the band between
    the walls' tags (between_walls): dropped explicitly, the start comes at once and on the road."""
    drive = both_walls_left_heard()
    est = run(key, drive)
    check_sane(key, drive, est)
    assert start_time(est) <= (14.0 if key == "dr" else 3.0)
    assert np.all(est.north_m < 3.0)  # never behind the left wall (north = +3 m)


# -- whatever arrives first ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", keys_for(ranges_before_odometry()))
def test_ranges_before_odometry(key):
    """The vehicle moves for 3 s before the first wheel/IMU sample: ignition uses no reading it cannot place."""
    drive = ranges_before_odometry()
    est = run(key, drive)
    check_sane(key, drive, est)
    assert start_time(est) >= 3.0
    if key.startswith("graph-batch"):
        assert errors(drive, est).max() < 1.5  # the smoothed track before the start too


@pytest.mark.parametrize("key", [k for k in GRAPH_KEYS])
def test_late_ranges_from_the_first_second(key):
    """Ranges arriving 0.5-2 s late from the start (graphs: filters apply late readings on arrival, by design)."""
    drive = late_ranges()
    est = run(key, drive)
    check_sane(key, drive, est)


# -- graph-batch solves a held track ignition never starts (GraphBuilder._start_from_graph) -------------------
def _never_igniting(monkeypatch) -> None:
    """Ignition that never determines a start (as on MRCLAM pieces where a creeping, turning robot sees one
    landmark at a time): only the graph's own solve can start the track."""
    from graphpos.ignition import Ignition

    monkeypatch.setattr(Ignition, "_solve", lambda self, *args, **kwargs: None)


def _planar(name: str):
    from graph_drives import SYNTHETIC_MODEL

    from graphpos.graph.config import GraphConfig

    return GRAPHS[name](GraphConfig(parameterisation="planar", **SYNTHETIC_MODEL))


def test_graph_batch_solves_a_track_ignition_never_starts(monkeypatch):
    """Offline, the held track's own graph determines its start: the whole drive comes out, close to the truth,
    with a start that says where it came from; online, graph-isam2 still waits for ignition (no output)."""
    from eval.metrics import evaluate_estimate

    _never_igniting(monkeypatch)
    drive = synthetic_drive(30.0, seed=1, turn_radps=0.1, compass=False)
    batch = _planar("graph-batch").run(drive.without_truth())
    assert batch.diagnostics["start"]["source"] == "graph" and batch.diagnostics["graph_start"][0]["result"] == "started"
    assert len(batch.t_s) > 250 and batch.t_s[0] < 1.0
    whole = evaluate_estimate(drive, batch)["windows"]["whole"]
    assert whole["position"]["rms_m"] < 0.3
    assert whole["nees"]["anees"] < 6.0
    online = _planar("graph-isam2").run(drive.without_truth())
    assert len(online.t_s) == 0 and online.diagnostics["not_started"]


def test_graph_batch_starts_a_long_track_from_a_piece_of_it(monkeypatch):
    """A held track longer than one piece (GRAPH_START_MAX_TRACK_S, here 12 s of a 30 s drive) is solved piece by
    piece from its end: the last piece (no range in it) cannot start it, the one before does, and the whole
    track comes out, close to the truth."""
    from eval.metrics import evaluate_estimate
    from graphpos.graph import builder

    _never_igniting(monkeypatch)
    monkeypatch.setattr(builder, "GRAPH_START_MAX_TRACK_S", 12.0)
    drive = synthetic_drive(30.0, seed=1, turn_radps=0.1, compass=False)
    rfid = drive.channels["rfid"]
    drive = drive.replace(channels={**drive.channels, "rfid": rfid.select(rfid.t_s < 17.0)})
    batch = _planar("graph-batch").run(drive.without_truth())
    assert batch.diagnostics["start"]["source"] == "graph"
    assert [p["result"] for p in batch.diagnostics["graph_start"]] == ["started"]
    assert 5.0 < batch.diagnostics["graph_start"][0]["t_s"] < 7.0  # the piece 6-18 s: 18-30 s has no range
    assert len(batch.t_s) > 250 and batch.t_s[0] < 1.0
    assert evaluate_estimate(drive, batch)["windows"]["whole"]["position"]["rms_m"] < 0.3


def test_graph_batch_leaves_an_ambiguous_track_unstarted(monkeypatch):
    """One beacon ranged from a straight track: mirrored tracks on either side of the beacon fit the ranges alike,
    so the graph's own solve refuses a start rather than give one of them (no output, the not-started diagnostic)."""
    _never_igniting(monkeypatch)
    drive = synthetic_drive(30.0, seed=1, beacons=[(60.0, 2.0, 0)], compass=False)
    batch = _planar("graph-batch").run(drive.without_truth())
    assert len(batch.t_s) == 0 and batch.diagnostics["not_started"]
    assert batch.diagnostics["graph_start"][0]["result"] == "ambiguous"
