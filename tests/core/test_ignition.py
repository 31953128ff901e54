"""graphpos.ignition alone: the start from known geometry, waiting while ambiguous, between_walls, StartPose."""

from __future__ import annotations

import math

import numpy as np
import pytest

import graphpos.ignition as ignition
from graphpos.errors import ConfigError
from graphpos.ignition import NOT_STARTED, UNKNOWN_SPEED_SIGMA_MPS, Ignition, IgnitionConfig, StartPose, between_walls


def wall_tags(length_m: float = 200.0, spacing_m: float = 6.0, walls: tuple[int, ...] = (+1, -1)) -> tuple[np.ndarray, np.ndarray]:
    """Tags every ``spacing_m`` along east at north = +3 (left, +1) and -3 (right, -1)."""
    pos, side = [], []
    for x in np.arange(0.0, length_m, spacing_m):
        for s in walls:
            pos.append((x, 3.0 * s))
            side.append(s)
    return np.array(pos), np.array(side)


def feed(ig: Ignition, duration_s: float, speed_mps=5.0, yaw_rate_radps=0.0, heard=None, compass=True, start=(0.0, 0.0, 0.0),
         seed=0, range_sigma_m=0.2, wheel=True, stop_when_started=True, range_scale=1.0, max_range_m=9.0):
    """Drive a constant speed / yaw rate path past ``heard`` tags (positions), feeding ignition like an estimator.

    Wheel and gyro at 20 Hz, compass (2 deg noise) at 10 Hz, ranges (within
    ``max_range_m``, read ``range_scale`` times long) at 1 Hz. Returns (state
    or None, truth function t -> (e, n, yaw)).
    ``speed_mps`` may be a function of time.
    """
    rng = np.random.default_rng(seed)
    speed = speed_mps if callable(speed_mps) else (lambda t: speed_mps)
    dt = 0.05
    e, n, yaw = start
    truth = {}
    state = None
    for i in range(int(round(duration_s / dt)) + 1):
        t = i * dt
        truth[round(t, 6)] = (e, n, yaw)
        v = speed(t)
        if wheel:
            state = ig.speed(t, v + rng.normal(0, 0.02)) or state
        state = ig.yaw_rate(t, yaw_rate_radps + rng.normal(0, 0.002)) or state
        if compass and i % 2 == 0:
            state = ig.compass(t, math.remainder(yaw + rng.normal(0, math.radians(2.0)), 2 * math.pi)) or state
        if heard is not None and i % 20 == 0:
            d = np.hypot(heard[:, 0] - e, heard[:, 1] - n)
            near = d <= max_range_m
            if near.any():
                r = range_scale * d[near] + rng.normal(0, range_sigma_m, near.sum())
                state = ig.ranges(t, heard[near], r, np.full(near.sum(), range_sigma_m)) or state
        if state is not None and stop_when_started:
            break
        e += v * dt * math.cos(yaw)
        n += v * dt * math.sin(yaw)
        yaw += yaw_rate_radps * dt
    return state, (lambda t_s: truth[round(t_s, 6)])


def assert_within_sigmas(state, truth, k=4.0):
    e, n, yaw = truth(state.t_s)
    assert math.hypot(state.east_m - e, state.north_m - n) < k * state.position_sigma_m, (state, (e, n, yaw))
    assert abs(math.remainder(state.yaw_rad - yaw, 2 * math.pi)) < k * state.yaw_sigma_rad + 1e-9, (state, (e, n, yaw))


# -- known geometry ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(3))
def test_both_walls_with_compass_start_within_sigmas(seed):
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    state, truth = feed(ig, 10.0, heard=tags, seed=seed)
    assert state is not None and state.source == "ranges" and state.t_s <= 2.0
    assert state.position_sigma_m <= ig.config.max_position_sigma_m and state.yaw_sigma_rad <= ig.config.max_yaw_sigma_rad
    assert_within_sigmas(state, truth)
    assert abs(state.speed_mps - 5.0) < 0.2 and state.speed_sigma_mps == ig.config.speed_sigma_mps


def test_heading_from_travel_without_compass():
    """No compass: the heading comes from the direction of travel, once min_travel_m is driven."""
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    state, truth = feed(ig, 10.0, heard=tags, compass=False, yaw_rate_radps=0.02, start=(1.0, 0.5, 0.1))
    assert state is not None and state.source == "ranges"
    assert_within_sigmas(state, truth)


def test_standing_still_without_compass_waits_then_starts_once_moving():
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    state, _ = feed(ig, 20.0, speed_mps=0.0, heard=tags, compass=False)
    assert state is None and ig.attempts >= 15  # readings enough, heading unobservable
    ig = Ignition(tags, side)
    state, truth = feed(ig, 30.0, speed_mps=lambda t: 0.0 if t < 10.0 else 3.0, heard=tags, compass=False)
    assert state is not None and state.t_s >= 10.0 + ig.config.min_travel_m / 3.0
    assert_within_sigmas(state, truth)


def test_standing_still_with_compass_starts():
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    state, truth = feed(ig, 10.0, speed_mps=0.0, heard=tags, start=(10.0, 0.0, 0.3))
    assert state is not None and state.t_s <= 2.0 and abs(state.speed_mps) < 0.1
    assert_within_sigmas(state, truth)


@pytest.mark.parametrize("seed", range(3))
def test_ranges_read_long_are_scaled_at_the_start(seed):
    """Plaza1's UWB ranges read 7 % long: four beacons 13-62 m away, no compass. Taken as exact, they placed the
    start 4.1 m off with a 0.77 m sigma; with their common scale solved for (significant here), the start is
    within its sigmas and reports the scale. Exact ranges keep a scale of 1 (not significant)."""
    beacons = np.array([[-30.0, 40.0], [12.0, 5.0], [-45.0, -20.0], [55.0, -30.0]])
    started = {}
    for scale in (1.07, 1.0):
        ig = Ignition(beacons, np.zeros(4))
        state, truth = feed(ig, 60.0, speed_mps=lambda t: 0.0 if t < 30.0 else 2.0, yaw_rate_radps=0.05, heard=beacons, compass=False,
                            seed=seed, range_sigma_m=0.5, range_scale=scale, max_range_m=100.0)
        assert state is not None
        assert_within_sigmas(state, truth, k=3.0)
        started[scale] = state
    assert started[1.07].range_scale == pytest.approx(1.07, abs=0.02) and started[1.0].range_scale == 1.0
    exact = Ignition(beacons, np.zeros(4), config=IgnitionConfig(range_scale_sigma=0.0))
    state, truth = feed(exact, 60.0, speed_mps=lambda t: 0.0 if t < 30.0 else 2.0, yaw_rate_radps=0.05, heard=beacons, compass=False,
                        seed=seed, range_sigma_m=0.5, range_scale=1.07, max_range_m=100.0)
    e, n, _ = truth(state.t_s)
    assert math.hypot(state.east_m - e, state.north_m - n) > 3.0 * state.position_sigma_m, "the case does not need the scale"


def test_fixes_start_with_the_heading_of_their_track():
    ig = Ignition()
    rng = np.random.default_rng(5)
    state = None
    for i in range(200):
        t = i * 0.05
        ig.speed(t, 4.0)
        ig.yaw_rate(t, 0.0)
        if i % 10 == 0:
            yaw = math.radians(30.0)
            state = ig.fix(t, 100.0 + 4.0 * t * math.cos(yaw) + rng.normal(0, 0.1), 50.0 + 4.0 * t * math.sin(yaw) + rng.normal(0, 0.1), 0.1)
        if state:
            break
    assert state is not None and state.source == "fix"
    assert abs(math.degrees(state.yaw_rad) - 30.0) < 3 * math.degrees(state.yaw_sigma_rad)
    assert math.hypot(state.east_m - (100 + 4 * state.t_s * math.cos(yaw)), state.north_m - (50 + 4 * state.t_s * math.sin(yaw))) < 0.5


# -- ambiguity and the wall mirror -------------------------------------------------------------------------------
def test_one_wall_straight_road_waits():
    """Left-wall tags only, straight road: the vehicle and its mirror across the wall fit equally well."""
    tags, side = wall_tags(walls=(+1,))
    ig = Ignition(tags, side)
    state, _ = feed(ig, 20.0, heard=tags)
    assert state is None and ig.attempts >= 15


def test_one_wall_heard_both_mapped_drops_the_mirror():
    """The same readings, with the right wall's tags in the map (failed, never heard): the mirror lies behind the
    left wall, outside the band between the walls: dropped (between_walls), the start comes, on the road."""
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    state, truth = feed(ig, 20.0, heard=tags[side > 0])
    assert state is not None and state.t_s <= 3.0
    assert -3.0 < state.north_m < 3.0
    assert_within_sigmas(state, truth)


def test_a_turn_near_one_wall_resolves_the_mirror():
    """Ranges to one wall's tags while turning: the mirror image would have turned the other way; with the
    compass (and the gyro's turn) it no longer fits, and the start comes on the right side."""
    tags, side = wall_tags(length_m=60.0, walls=(+1,))
    # drive east 4 s, then turn right (away from the left wall) at 0.2 rad/s
    ig = Ignition(tags, side)
    rng = np.random.default_rng(3)
    e = n = yaw = 0.0
    state = None
    for i in range(400):
        t = i * 0.05
        w = -0.2 if t > 4.0 else 0.0
        ig.speed(t, 5.0)
        ig.yaw_rate(t, w)
        if i % 2 == 0:
            state = ig.compass(t, yaw + rng.normal(0, math.radians(2.0))) or state
        if i % 20 == 0:
            d = np.hypot(tags[:, 0] - e, tags[:, 1] - n)
            near = d <= 9.0
            if near.any():
                state = ig.ranges(t, tags[near], d[near] + rng.normal(0, 0.2, near.sum()), np.full(near.sum(), 0.2)) or state
        if state:
            break
        e += 5.0 * 0.05 * math.cos(yaw)
        n += 5.0 * 0.05 * math.sin(yaw)
        yaw += w * 0.05
    assert state is not None and state.t_s > 4.0, "started before the turn, on a mirror-ambiguous straight"
    assert math.hypot(state.east_m - e, state.north_m - n) < 4 * state.position_sigma_m
    assert abs(math.remainder(state.yaw_rad - yaw, 2 * math.pi)) < 4 * state.yaw_sigma_rad


@pytest.mark.parametrize("compass", [False, True])
def test_the_batched_multi_start_keeps_every_minimum_least_squares_finds_that_can_matter(monkeypatch, compass):
    """The batched descent (``_distinct_minima``) stands in for one ``least_squares`` call per start: on a
    one-wall straight road (two mirror minima and the turned tracks), with and without the compass, the best
    minimum of the per-start solves and every one within the rival margin of it are among its minima, at
    the same place and cost."""
    seen = []
    real = ignition._distinct_minima

    def recording(residuals, starts, **kwargs):
        minima = real(residuals, starts, **kwargs)
        seen.append((residuals, starts, minima))
        return minima

    monkeypatch.setattr(ignition, "_distinct_minima", recording)
    tags, side = wall_tags(walls=(+1,))
    ig = Ignition(tags, side)
    feed(ig, 12.0, heard=tags, compass=compass, seed=4)
    assert len(seen) >= 5
    margin = IgnitionConfig().chi2_margin / 2
    for residuals, starts, minima in seen[::2]:
        fits = [ignition.least_squares(lambda x: residuals(x)[0][0], x0, jac=lambda x: residuals(x)[1][0], loss="soft_l1",
                                       f_scale=2.0, max_nfev=100, xtol=1e-12, ftol=1e-12, gtol=1e-12) for x0 in starts]
        best = min(f.cost for f in fits)
        mattering = [f for f in fits if f.cost <= best + margin]
        assert len(mattering) >= 2  # the mirror
        for f in mattering:
            same = [cost for x, cost in minima
                    if math.hypot(*(x[:2] - f.x[:2])) < 1e-3 and abs(math.remainder(x[2] - f.x[2], 2 * math.pi)) < 1e-4]
            assert same and abs(same[0] - f.cost) < 1e-6 * (1.0 + f.cost), (f.x, f.cost, minima)


@pytest.mark.parametrize("position, expected", [
    ((10.0, 0.0), True),  # on the road
    ((10.0, 2.9), True),  # beside the left wall
    ((10.0, 4.4), True),  # within the quarter-width margin (u = -0.23)
    ((10.0, 6.0), False),  # the mirror across the left wall (u = -0.5)
    ((10.0, -6.0), False),  # the mirror across the right wall (u = 1.5)
])
def test_between_walls(position, expected):
    tags, side = wall_tags()
    assert between_walls(np.array(position), tags, side) is expected


@pytest.mark.parametrize("position, expected", [
    ((-150.0, 0.0), True),  # on the approach road, 150 m before the first tag
    ((40.0, 1.0), True),  # on the road between a left tag and a right tag 81 m on
    ((40.0, 8.0), False),  # the mirror of (40, 1) across the left wall
    ((120.0, -8.0), False),  # the mirror of (120, -1) across the right wall
    ((300.0, 2.0), True),  # past the last tags
])
def test_between_walls_with_staggered_sparse_tags(position, expected):
    """Staggered tags 163 m apart per wall: the nearest left and right tags are 81 m apart along the road,
    so the band between them says nothing about the sides; each wall's own line does."""
    tags = np.array([[0.0, 4.5], [81.8, -4.5], [163.6, 4.5], [245.4, -4.5]])
    assert between_walls(np.array(position), tags, np.array([1, -1, 1, -1])) is expected


def test_between_walls_says_nothing_without_both_walls():
    tags, side = wall_tags(walls=(+1,))
    assert between_walls(np.array([10.0, 6.0]), tags, side)
    assert between_walls(np.array([10.0, 6.0]), np.zeros((0, 2)), np.zeros(0))
    beacons = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert between_walls(np.array([5.0, 50.0]), beacons, np.zeros(2))  # beacons on no wall (side 0)


# -- undeterminable readings: no solve at all ---------------------------------------------------------------------
def _count_solves(monkeypatch) -> list:
    calls = []
    real = ignition.least_squares

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(ignition, "least_squares", counted)
    return calls


def test_one_landmark_without_heading_is_never_solved(monkeypatch):
    """Ranges to one beacon, no compass: turning the track about the beacon changes no range."""
    calls = _count_solves(monkeypatch)
    ig = Ignition(np.array([[20.0, 10.0]]), np.zeros(1))
    state, _ = feed(ig, 30.0, yaw_rate_radps=0.2, heard=np.array([[20.0, 10.0]]), compass=False)
    assert state is None and ig.attempts > 0 and not calls


def test_too_few_constraints_are_never_solved(monkeypatch):
    """One range and the compass: two constraints for three unknowns."""
    calls = _count_solves(monkeypatch)
    ig = Ignition()
    state = None
    for i in range(100):
        t = i * 0.1
        ig.speed(t, 5.0)
        ig.yaw_rate(t, 0.0)
        state = ig.compass(t, 0.0) or state
        if i == 20:
            state = ig.ranges(t, np.array([[10.0, 3.0]]), np.array([5.0]), np.array([0.3])) or state
    assert ig.finish() is None and state is None and not calls


def test_one_landmark_with_compass_is_solved(monkeypatch):
    calls = _count_solves(monkeypatch)
    beacon = np.array([[10.0, 4.0]])
    ig = Ignition(beacon, np.zeros(1))
    feed(ig, 4.0, heard=beacon, compass=True)
    assert calls and ig.attempts >= 3


# -- what arrives first -------------------------------------------------------------------------------------------
def test_readings_before_the_first_wheel_speed_are_not_used():
    """Ranges and compass while the vehicle moves but the wheel has not spoken yet: not placeable, not used."""
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    rng = np.random.default_rng(2)
    state = None
    for i in range(200):
        t = i * 0.05
        e = 5.0 * t
        if t >= 3.0:
            state = ig.speed(t, 5.0) or state
            ig.yaw_rate(t, 0.0)
        if i % 2 == 0:
            state = ig.compass(t, rng.normal(0, 0.03)) or state
        if i % 20 == 0:
            d = np.hypot(tags[:, 0] - e, tags[:, 1])
            near = d <= 9.0
            state = ig.ranges(t, tags[near], d[near] + rng.normal(0, 0.2, near.sum()), np.full(near.sum(), 0.2)) or state
        if state:
            break
    assert state is not None and state.t_s >= 3.0
    assert math.hypot(state.east_m - 5.0 * state.t_s, state.north_m) < 4 * state.position_sigma_m
    assert abs(state.speed_mps - 5.0) < 0.1


def test_without_wheel_the_speed_is_unknown_and_the_heading_from_the_compass():
    tags, side = wall_tags()
    ig = Ignition(tags, side, has_wheel=False)
    state, truth = feed(ig, 5.0, heard=tags, wheel=False, start=(20.0, 0.0, 0.0))
    assert state is not None and state.speed_sigma_mps == UNKNOWN_SPEED_SIGMA_MPS and state.speed_mps == 0.0
    assert_within_sigmas(state, truth)


def test_without_wheel_the_scans_of_different_places_are_not_mixed():
    """No dead reckoning relates two scans 1 s apart of a vehicle at 22 m/s (22 m): solved together they
    disagree, and the start comes from the latest scan's readings alone, as if the earlier had not been heard."""
    tags, side = wall_tags()

    def scan(ig, t_s, east_m, heard):
        d = np.hypot(heard[:, 0] - east_m, heard[:, 1])
        near = d <= 9.0
        ranges = d[near] + np.random.default_rng(int(t_s)).normal(0, 0.3, near.sum())
        return ig.ranges(t_s, heard[near], ranges, np.full(near.sum(), 0.3))

    across = tags[np.isclose(tags[:, 0], 18.0)]  # the two tags facing each other at east 18 m
    both = Ignition(tags, side, has_wheel=False)
    assert scan(both, 0.0, 20.0, across) is None  # ahead of that pair or behind it: it waits
    state = scan(both, 1.0, 42.0, tags)
    alone = scan(Ignition(tags, side, has_wheel=False), 1.0, 42.0, tags)
    assert state is not None and alone is not None
    assert (state.east_m, state.north_m, state.position_sigma_m) == pytest.approx((alone.east_m, alone.north_m, alone.position_sigma_m), abs=1e-9)
    assert math.hypot(state.east_m - 42.0, state.north_m) < 4 * state.position_sigma_m


def test_without_wheel_or_compass_the_heading_is_left_unknown():
    tags, side = wall_tags()
    ig = Ignition(tags, side, has_wheel=False)
    state, truth = feed(ig, 5.0, heard=tags, wheel=False, compass=False, start=(20.0, 0.0, 0.0))
    assert state is not None and state.yaw_rad == 0.0 and state.yaw_sigma_rad == math.pi
    e, n, _ = truth(state.t_s)
    assert math.hypot(state.east_m - e, state.north_m - n) < 4 * state.position_sigma_m


def test_user_pose_is_the_start_at_the_first_wheel_speed_moving_at_it():
    """A user's pose starts the estimator at the speed the wheel reads, not at rest (fusion-ekf 0.25 -> 0.36 m RMS
    from the true start pose of a drive at 2 m/s, before)."""
    pose = StartPose(12.0, -3.0, math.radians(90.0), 0.5, math.radians(2.0))
    ig = Ignition(user=pose)
    assert ig.yaw_rate(7.49, 0.0) is None  # the IMU first: the speed is not known yet
    state = ig.speed(7.5, 3.0)
    assert state is not None and state.source == "user" and state.t_s == 7.5
    assert (state.east_m, state.north_m, state.yaw_rad, state.position_sigma_m) == (12.0, -3.0, math.radians(90.0), 0.5)
    assert state.speed_mps == 3.0 and state.v_north_mps == pytest.approx(3.0) and abs(state.v_east_mps) < 1e-12
    # readings change nothing afterwards
    assert ig.ranges(8.0, np.array([[0.0, 0.0]]), np.array([1.0]), np.array([0.1])) is state


def test_user_pose_without_a_wheel_is_the_start_at_the_first_measurement():
    ig = Ignition(user=StartPose(1.0, 2.0, 0.0), has_wheel=False)
    state = ig.yaw_rate(3.0, 0.1)
    assert state is not None and state.t_s == 3.0 and state.speed_mps == 0.0
    assert state.speed_sigma_mps == UNKNOWN_SPEED_SIGMA_MPS
    # an estimator that asks at its first measurement (RFID-only filters) gets the pose at once
    assert Ignition(user=StartPose(1.0, 2.0, 0.0)).at(4.0).t_s == 4.0


def test_finish_makes_a_last_attempt_within_the_solve_period():
    tags, side = wall_tags()
    ig = Ignition(tags, side, config=IgnitionConfig(solve_every_s=100.0))
    for i in range(21):
        t = i * 0.1
        ig.speed(t, 0.0)
        ig.compass(t, 0.0)
    assert ig.ranges(0.0, tags[:1], np.array([3.0]), np.array([0.2])) is None  # attempted: one range, undetermined
    assert ig.ranges(2.0, tags[1:4], np.hypot(*tags[1:4].T), np.full(3, 0.2)) is None  # within the solve period: no attempt
    state = ig.finish()
    assert state is not None and math.hypot(state.east_m, state.north_m) < 4 * state.position_sigma_m


# -- StartPose -------------------------------------------------------------------------------------------------------
def test_start_pose_parse_and_params():
    p = StartPose.parse("10, -2.5, 90")
    assert (p.east_m, p.north_m) == (10.0, -2.5) and p.yaw_rad == pytest.approx(math.pi / 2)
    assert p.position_sigma_m == 1.0 and p.yaw_sigma_rad == pytest.approx(math.radians(5.0))
    q = StartPose.parse("1,2,180,0.5,10")
    assert q.position_sigma_m == 0.5 and q.yaw_sigma_rad == pytest.approx(math.radians(10.0))
    assert StartPose.from_params({"initial_pose": q.to_dict()}) == q
    assert StartPose.from_params({}) is None


@pytest.mark.parametrize("text", ["1,2", "a,b,c", "1,2,3,4,5,6", "1,2,nan", "1e9,0,0", "0,0,0,-1", "0,0,0,1,0"])
def test_start_pose_refuses_bad_text(text):
    with pytest.raises(ConfigError):
        StartPose.parse(text)


@pytest.mark.parametrize("stored", [{"east_m": 1.0}, "1,2,3", {"east_m": 1.0, "north_m": 2.0, "yaw_rad": float("inf")}])
def test_start_pose_refuses_bad_params(stored):
    with pytest.raises(ConfigError):
        StartPose.from_params({"initial_pose": stored})


def test_an_estimator_that_never_starts_says_why_the_last_attempt_failed():
    """It said only "give --initial-pose, or a drive with fixes or ranges while moving", also on a drive with ranges
    while moving whose start missed dead reckoning's 1-degree heading limit (MRCLAM6 robot 3)."""
    tags, side = wall_tags()
    ig = Ignition(tags, side)
    assert ig.not_started() == NOT_STARTED  # nothing attempted yet
    assert feed(ig, 5.0, speed_mps=0.0, heard=tags, compass=False)[0] is None
    assert ig.not_started().startswith(NOT_STARTED) and "no compass, and the vehicle had moved 0.0" in ig.not_started()  # wheel noise
    strict = Ignition(tags, side, config=IgnitionConfig(max_yaw_sigma_rad=math.radians(0.01)))
    assert feed(strict, 5.0, heard=tags)[0] is None
    assert "deg of heading, over this estimator's" in strict.not_started()
