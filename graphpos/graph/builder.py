"""Turns a measurement stream into keyframes and GTSAM factors.

Keyframes are laid on a regular grid ``t_k = t_0 + k / rate`` starting at the
first measurement. Keyframe ``k`` is closed when a measurement arrives after
``t_k``: the wheel/gyro (and IMU) samples up to ``t_k`` are preintegrated into
the odometry factors between ``k - 1`` and ``k``. Every absolute measurement
(tag/RSU range, RSU/GNSS fix, compass yaw) is attached to the keyframe
nearest its own timestamp ``t_s`` — also when it arrives late: a reading for
a keyframe already in the graph goes into the next update, up to
``max_delay_s`` late (issue 6, item 4).

Start-up (the shared :mod:`graphpos.ignition`): with a start pose from the
user, keyframe 0 gets a prior with the user's sigmas. Otherwise keyframes
are held back (no output) and every measurement also goes to ignition,
which solves the start from fixes or ranges with the dead-reckoned motion;
when it gives a start state, the held track is moved rigidly (turned and
shifted) onto it and released to the smoother with a prior at the
keyframe of the start, wide (three times ignition's sigmas: the readings
ignition used are in the graph too) but enough to keep the system
determinate whatever the readings (never IndeterminantLinearSystem). A
drive on which ignition never succeeds gives no output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, R

from graphpos.drive import Channel, Drive, Measurement
from graphpos.graph.config import GraphConfig
from graphpos.ignition import Ignition, IgnitionConfig, StartPose, StartState
from graphpos.profile import SensorProfile
from graphpos.graph.models import KeyframeState, robust
from graphpos.graph.odometry import OdometryDelta, PlanarOdometry

#: A landmark key is reused for sightings at most this far apart, s.
LANDMARK_LIFETIME_S = 3.0
#: Factor on ignition's sigmas for the start prior of the released track.
START_PRIOR_INFLATION = 3.0
#: The graph starts from a looser heading than a filter (ignition's default
#: 10 degrees): the start only sets the linearisation point and a wide prior,
#: and the graph resolves the heading from every range it holds. On the slow
#: MRCLAM robots, 5 degrees took 100-400 s of driving (10 degrees: robot 1 still 386 s).
START_MAX_YAW_SIGMA_RAD = math.radians(15.0)


@dataclass
class Increment:
    """What one closed keyframe adds to the smoother."""

    keyframe: int
    t_s: float
    factors: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    values: gtsam.Values = field(default_factory=gtsam.Values)
    timestamps: dict[int, float] = field(default_factory=dict)
    released: list[int] = field(default_factory=list)  # keyframes entering the smoother now
    anchoring: bool = False  # first information of the trajectory: iterate more


@dataclass
class RangeRecord:
    """A range factor's ingredients, kept to rebuild it with another range scale or sigma.

    ``sigma_from_model``: the sigma is the range model's at the estimated
    distance (tag readings), re-evaluated by :meth:`GraphBuilder.reweight_ranges`;
    otherwise it came with the reading (RSU ranges).
    """

    keyframe: int
    landmark_key: int
    reading_m: float
    sigma_m: float
    sigma_from_model: bool = False


class GraphBuilder:
    """Keyframes and factors from measurements in arrival order.

    Parameters
    ----------
    config : GraphConfig
    model : PlanarModel or InertialModel
    drive : Drive
        Maps only (tags, RSUs).
    range_model : RangeModel
        RFID reading -> distance and sigma.
    max_delay_s : float
        Latest arrival accepted for a reading of an existing keyframe.
    landmark_lifetime_s : float
        A landmark key unused for longer gets a fresh key. Landmarks are
        known points held by tight priors, so a fresh key per sighting loses
        nothing, and it keeps the Bayes tree free of loop closures: one key
        per beacon across a whole drive (Plaza: 4 beacons, 32 minutes) makes
        every iSAM2 update re-eliminate most of the tree. Fixed-lag smoothers
        also marginalise old keys, which cannot come back.
    keep_history : bool
        Keep every factor (for batch solves and range-scale estimation).
    range_scale : float
        Readings are divided by this scale (``reading = scale * distance``).
    initial_pose : StartPose or None
        A start pose from the user (prior with its sigmas at keyframe 0);
        None: ignition finds the start.
    release_window_s : float
        Without history, how much of the held start-up track is released
        to the smoother at anchoring.
    """

    def __init__(
        self,
        config: GraphConfig,
        model,
        drive: Drive,
        range_model,
        max_delay_s: float,
        landmark_lifetime_s: float = LANDMARK_LIFETIME_S,
        keep_history: bool = True,
        range_scale: float = 1.0,
        initial_pose: StartPose | None = None,
        release_window_s: float = math.inf,
    ):
        self.config = config
        self.model = model
        self.range_model = range_model
        self.max_delay_s = max_delay_s
        self.landmark_lifetime_s = landmark_lifetime_s
        self.keep_history = keep_history
        self.range_scale = range_scale
        self.initial_pose = initial_pose
        self.release_window_s = release_window_s if not keep_history else math.inf
        self.period_s = 1.0 / config.keyframe_rate_hz
        self.tags = {int(i): (float(e), float(n), int(w)) for i, e, n, w in zip(drive.tags.tag_id, drive.tags.east_m, drive.tags.north_m, drive.tags.wall_side)}
        self.rsus = {int(i): (float(e), float(n)) for i, e, n in zip(drive.rsus.rsu_id, drive.rsus.east_m, drive.rsus.north_m)}
        c = config
        self.odometry = PlanarOdometry(
            speed_density=c.wheel_speed_sigma_mps / math.sqrt(c.wheel_rate_hz),
            yaw_rate_density=c.gyro_sigma_radps / math.sqrt(c.imu_rate_hz),
            slip_density=c.lateral_slip_sigma_mps / math.sqrt(c.wheel_rate_hz),
            heading_drift_sigma_radps=c.heading_drift_sigma_radps,
            speed_scale_density=c.wheel_scale_density_per_sqrt_s,
            heading_density=c.heading_noise_radps_per_sqrt_s,
            turn_scale_density=c.turn_scale_density_per_sqrt_s,
            has_speed=drive.has("wheel"),
            has_yaw_rate=drive.has("imu"),
        )
        self.has_compass = drive.has("compass")
        self.pim = model.new_preintegration(None)
        self._imu_held: tuple[np.ndarray, np.ndarray] | None = None
        self._imu_t: float | None = None
        self.t0: float | None = None
        self.last_keyframe = -1
        self.states: dict[int, KeyframeState] = {}
        self.speeds: dict[int, float] = {}
        self._waiting: dict[int, list[tuple]] = {}  # readings for keyframes not closed yet
        self._ready: list[tuple[int, tuple]] = []  # readings for closed keyframes, next update
        self._landmarks: dict[tuple[str, int], tuple[int, float]] = {}
        self._landmark_count = 0
        self.anchored = initial_pose is not None
        self._backlog: list[Increment] = []
        self._backlog_landmarks: dict[int, np.ndarray] = {}
        self.ignition = Ignition(np.column_stack([drive.tags.east_m, drive.tags.north_m]), drive.tags.wall_side, has_wheel=drive.has("wheel"),
                                 config=IgnitionConfig(compass_sigma_rad=config.compass_sigma_rad, max_yaw_sigma_rad=START_MAX_YAW_SIGMA_RAD))
        self._start: StartState | None = None
        #: Corrections of the incoming yaw rates and wheel speeds learnt online (:meth:`recalibrate`).
        self.corrections = SensorProfile()
        # history for batch solves / scale estimation
        self.fixed_factors = gtsam.NonlinearFactorGraph()
        self.range_records: list[RangeRecord] = []
        self.odometry_records: list[tuple[int, OdometryDelta]] = []
        self.wheel_scale: float | None = None  # None: wheel factors as built online
        self.wheel_drift_density: float | None = None  # with wheel_scale None: rebuild the drift term at this density
        self.landmark_positions: dict[int, np.ndarray] = {}
        self.diagnostics = {"late_attached": 0, "late_dropped": 0, "before_odometry": 0, "ranges": 0, "anchor_keyframe": None, "start": None}
        if initial_pose is not None:
            self.diagnostics["start"] = {"source": "user", **initial_pose.to_dict()}

    # -- time grid ----------------------------------------------------------
    def keyframe_time(self, k: int) -> float:
        return self.t0 + k * self.period_s

    def _nearest_keyframe(self, t_s: float) -> int:
        return int(math.floor((t_s - self.t0) / self.period_s + 0.5))

    # -- input ----------------------------------------------------------------
    def add(self, m: Measurement) -> list[Increment]:
        """Take one measurement; return the keyframes it closes.

        The keyframe grid starts at the first odometry (wheel or IMU)
        sample: an absolute reading before it cannot be placed relative to
        the motion (counted as ``before_odometry`` and dropped).
        """
        if self.t0 is None:
            if m.channel not in ("imu", "wheel"):
                self.diagnostics["before_odometry"] += 1
                return []
            self.t0 = m.t_s
            self.odometry.start(m.t_s)
            self._imu_t = m.t_s
        closed = []
        arrival = m.arrival_s
        while self.keyframe_time(self.last_keyframe + 1) < arrival - 1e-9:
            closed.append(self._close(self.last_keyframe + 1, arrival))
        self._take(m, arrival)
        return closed

    def flush(self, end_s: float | None = None) -> list[Increment]:
        """Close the keyframes up to ``end_s`` (default: the last waiting reading) and release any backlog."""
        closed = []
        last = max(self._waiting, default=self.last_keyframe)
        if end_s is not None:
            last = max(last, self._nearest_keyframe(end_s))
        while self.last_keyframe < last or self._ready:
            k = self.last_keyframe + 1
            closed.append(self._close(k, self.keyframe_time(k) + 1e-6))
        if not self.anchored and self._backlog:
            self._ignite(self.ignition.finish())
            if self._start is not None:
                closed.append(self._release(closed[-1] if closed else None, self._move_onto_start(self._start)))
        return closed

    def _take(self, m: Measurement, arrival: float) -> None:
        v = m.values
        ch = m.channel
        if ch == "imu":
            yaw_rate = (v["yaw_rate_radps"] - self.corrections.gyro_bias_radps) / self.corrections.yaw_rate_scale
            self.odometry.advance(m.t_s)
            self.odometry.set_yaw_rate(yaw_rate)
            if not self.anchored:
                self._ignite(self.ignition.yaw_rate(m.t_s, yaw_rate))
            if self.pim is not None:
                self._integrate_imu(m.t_s)
                self._imu_held = (
                    np.array([v["accel_x_mps2"], v["accel_y_mps2"], 9.81]),
                    np.array([0.0, 0.0, yaw_rate]),
                )
            return
        if ch == "wheel":
            speed = v["speed_mps"] / self.corrections.wheel_scale
            self.odometry.advance(m.t_s)
            self.odometry.set_speed(speed)
            if not self.anchored:
                self._ignite(self.ignition.speed(m.t_s, speed))
            return
        if ch == "rfid":
            reading = Channel("rfid", {k: [x] for k, x in v.items()}, validate=False)
            d, s = self.range_model.ranges(reading)
            if not (np.isfinite(d[0]) and np.isfinite(s[0]) and s[0] > 0):
                return
            # the sigma at the reading's own distance stands in until the
            # keyframe's estimate gives a better one (see _range_sigma_m)
            entry = ("range", ("tag", int(v["tag_id"])), float(d[0]), float(s[0]) * self.config.range_sigma_scale, True)
        elif ch == "rsu":
            rid = int(v["rsu_id"])
            if np.isfinite(v.get("range_m", np.nan)):
                entry = ("range", ("rsu", rid), float(v["range_m"]), float(v["sigma_m"]), False)
            else:
                entry = ("fix", float(v["east_m"]), float(v["north_m"]), float(v["sigma_m"]))
        elif ch == "gnss":
            entry = ("fix", float(v["east_m"]), float(v["north_m"]), float(v["sigma_m"]))
        elif ch == "compass":
            entry = ("compass", float(v["yaw_rad"]))
        else:
            return
        if not self.anchored:
            self._ignite_with(m.t_s, entry)
        k = max(self._nearest_keyframe(m.t_s), 0)
        if k > self.last_keyframe:
            self._waiting.setdefault(k, []).append(entry)
        elif arrival - self.keyframe_time(k) <= self.max_delay_s + 0.5 * self.period_s and self._keyframe_alive(k):
            self._ready.append((k, entry))
            self.diagnostics["late_attached"] += 1
        else:
            self.diagnostics["late_dropped"] += 1

    # -- start-up -------------------------------------------------------------
    def _ignite_with(self, t_s: float, entry: tuple) -> None:
        """Give an absolute reading to ignition (before the track is anchored)."""
        kind = entry[0]
        if kind == "compass":
            state = self.ignition.compass(t_s, entry[1])
        elif kind == "fix":
            state = self.ignition.fix(t_s, entry[1], entry[2], entry[3])
        else:
            _, which, reading, sigma, _ = entry
            mark = np.array([self._landmark_position(which)])
            state = self.ignition.ranges(t_s, mark, np.array([reading / self.range_scale]), np.array([sigma / self.range_scale]))
        self._ignite(state)

    def _ignite(self, state: StartState | None) -> None:
        if state is not None and self._start is None:
            self._start = state
            self.diagnostics["start"] = state.describe()

    def recalibrate(self, corrections: SensorProfile, range_scale: float, range_model) -> None:
        """Use learnt corrections from now on: readings still to come are corrected, new factors get the noise levels.

        ``corrections``: the yaw-rate and wheel corrections (of raw readings)
        and noise levels; ``range_scale`` and ``range_model`` (a sigma) for
        tag ranges still to come. Factors already built stay as they are.
        """
        self.corrections = corrections
        self.range_scale = range_scale
        if range_model is not None:
            self.range_model = range_model
        o = self.odometry
        if corrections.heading_noise_radps_per_sqrt_s is not None:
            o.heading_var = corrections.heading_noise_radps_per_sqrt_s**2
        if corrections.turn_scale_density_per_sqrt_s is not None:
            o.turn_scale_var = corrections.turn_scale_density_per_sqrt_s**2

    def _keyframe_alive(self, k: int) -> bool:
        return k in self.states

    def _integrate_imu(self, t_s: float) -> None:
        dt = t_s - self._imu_t
        if self._imu_held is not None and dt > 0:
            self.pim.integrateMeasurement(self._imu_held[0], self._imu_held[1], dt)
        if dt > 0 or self._imu_held is None:
            self._imu_t = t_s

    # -- keyframes ------------------------------------------------------------
    def _initial_state(self) -> KeyframeState:
        """Keyframe 0: the user's start pose, else the origin heading east (moved onto ignition's start later)."""
        p = self.initial_pose
        e, n, yaw = (p.east_m, p.north_m, p.yaw_rad) if p is not None else (0.0, 0.0, 0.0)
        v = self.odometry.speed_mps
        return KeyframeState(float(e), float(n), float(yaw), v * math.cos(yaw), v * math.sin(yaw))

    def _close(self, k: int, arrival: float) -> Increment:
        t_k = self.keyframe_time(k)
        inc = Increment(k, t_k)
        delta = self.odometry.cut(t_k)
        if self.pim is not None:
            self._integrate_imu(t_k)
        entries = self._waiting.pop(k, [])
        if k == 0:
            state = self._initial_state()
            inc.anchoring = self.anchored
            if self.anchored:
                p = self.initial_pose
                self._add(inc, self.model.prior_factors(0, state, p.position_sigma_m, p.yaw_sigma_rad))
        else:
            state = self.model.predict(self.states[k - 1], delta, self.pim)
            wheel, *others = self.model.odometry_factors(k, delta, self.pim)
            inc.factors.add(wheel)
            if self.keep_history:
                self.odometry_records.append((k, delta))
            self._add(inc, others)
        self.states[k] = state
        self.speeds[k] = delta.mean_speed_mps
        self.model.insert_values(inc.values, k, state)
        for key in self.model.keyframe_keys(k):
            inc.timestamps[key] = t_k
        self._add(inc, self.model.keyframe_factors(k, state))
        if self.pim is not None:
            self.pim = self.model.new_preintegration(state.bias)
        self.last_keyframe = k
        ready = [(k, e) for e in entries] + self._ready
        self._ready = []
        if not self.anchored:
            self._backlog.append(inc)
            self._attach(inc, ready)
            if self._start is None:
                inc.released = []
                self._prune(k)
                return inc
            return self._release(inc, self._move_onto_start(self._start))
        self._attach(inc, ready)
        inc.released = [k]
        self._prune(k)
        return inc

    def _prune(self, k: int) -> None:
        """Forget states no late reading can refer to (fixed-lag memory stays flat)."""
        if self.keep_history or not self.anchored:
            return
        old = k - int(math.ceil((self.max_delay_s + 1.0) / self.period_s)) - 1
        self.states.pop(old, None)
        self.speeds.pop(old, None)

    def _add(self, inc: Increment, factors: list) -> None:
        for f in factors:
            inc.factors.add(f)
            if self.keep_history:
                self.fixed_factors.add(f)

    # -- absolute measurements ------------------------------------------------
    def _attach(self, inc: Increment, ready: list[tuple[int, tuple]]) -> None:
        c = self.config
        for k, entry in ready:
            kind = entry[0]
            if kind == "compass":
                self._add(inc, [self.model.compass_factor(k, entry[1], c.compass_sigma_rad)])
            elif kind == "fix":
                _, e, n, s = entry
                dim = self.model.fix_dim()
                sig = np.array([s, s, 1e3]) if dim == 3 else s
                self._add(inc, [self.model.fix_factor(k, e, n, robust(sig, c, dim))])
            else:
                _, which, reading, sigma, from_model = entry
                key = self._landmark_key(inc, which, k)
                if from_model and self.anchored and k in self.states:
                    s, (e, n) = self.states[k], self._landmark_position(which)
                    at_estimate = float(self._range_sigma_m(np.array([math.hypot(s.east_m - e, s.north_m - n) * self.range_scale]))[0])
                    sigma = at_estimate if math.isfinite(at_estimate) else sigma
                if self.keep_history:
                    self.range_records.append(RangeRecord(k, key, reading, sigma, from_model))
                noise = robust(sigma / self.range_scale, c)
                inc.factors.add(self.model.range_factor(k, key, reading / self.range_scale, noise))
                self.diagnostics["ranges"] += 1

    def _range_sigma_m(self, distance_m: np.ndarray) -> np.ndarray:
        """The range model's sigma at estimated distances (times ``range_sigma_scale``).

        A tag reading's noise depends on the true distance (RSS fading is
        multiplicative: decimetres at 1 m, metres at 8 m; see
        :mod:`graphpos.ranging.sigma`). Evaluated at the reading's own
        distance, readings that happen to come out short get the smallest
        sigmas, and the solution is pulled towards the tags: on
        paper-straight, 0.1-0.5 m towards the near wall (graph-batch's mean
        cross-track error over 8 seeds: -0.33 m; at the estimate's
        distance: -0.04 m). The estimate's distance has no such correlation
        with the reading's error. Non-finite sigmas come back as NaN.
        """
        sigma = np.asarray(self.range_model.predict_sigma_m(np.asarray(distance_m, dtype=np.float64)), dtype=np.float64)
        return np.where(np.isfinite(sigma) & (sigma > 0), sigma * self.config.range_sigma_scale, np.nan)

    def reweight_ranges(self, values: gtsam.Values) -> None:
        """Re-evaluate every tag range's sigma at the distance of a solved trajectory (``keep_history``)."""
        records = [r for r in self.range_records if r.sigma_from_model]
        if not records:
            return
        pos = np.array([self.model.position(values, r.keyframe) for r in records])
        marks = np.array([self.landmark_positions[r.landmark_key] for r in records])
        sigma = self._range_sigma_m(np.hypot(*(pos - marks).T) * self.range_scale)
        for r, s in zip(records, sigma):
            if np.isfinite(s):
                r.sigma_m = float(s)

    def range_factor(self, record: RangeRecord, scale: float):
        """Rebuild a recorded range factor for another range scale."""
        noise = robust(record.sigma_m / scale, self.config)
        return self.model.range_factor(record.keyframe, record.landmark_key, record.reading_m / scale, noise)

    def graph(self, scale: float | None = None, extra_turn_density2: float = 0.0) -> gtsam.NonlinearFactorGraph:
        """Every factor so far (``keep_history``): ranges built with ``scale``, wheel factors with
        :attr:`wheel_scale` (else with the drift term at :attr:`wheel_drift_density`, else as built online),
        their heading loosened by ``extra_turn_density2`` (:meth:`OdometryDelta.with_turn_density`)."""
        scale = self.range_scale if scale is None else scale
        g = gtsam.NonlinearFactorGraph(self.fixed_factors)
        for r in self.range_records:
            g.add(self.range_factor(r, scale))
        for k, delta in self.odometry_records:
            if self.wheel_scale is None and self.wheel_drift_density is not None:
                delta = delta.with_drift_density(self.wheel_drift_density)
            if extra_turn_density2 > 0:
                delta = delta.with_turn_density(extra_turn_density2)
            g.add(self.model.wheel_factor(k, delta, self.wheel_scale))
        return g

    def fit_wheel_scale(self, values: gtsam.Values, since_keyframe: int = 0) -> float:
        """Wheel scale (``reading = scale * true``) fitting the wheel deltas to a solved trajectory.

        Least squares of ``solved = measured / scale`` over the keyframe
        translations (body frame); the solved trajectory must come from a
        graph whose wheel factors allow for a scale error (the drift term).
        The solved translations are the noisy side (the trajectory jitters
        by centimetres from keyframe to keyframe as it follows the ranges),
        the wheel's the precise one, so the solved ones are regressed on the
        measured: regressing the other way divides by the jitter-inflated
        ``sum(solved**2)`` and biased the scale low (0.5 % on a 40 s drive at
        5 m/s with no scale error).
        """
        records = [(k, d) for k, d in self.odometry_records if k > since_keyframe and values.exists(self.model.pose_key(k - 1))]
        measured = np.array([[d.dx_m, d.dy_m] for _, d in records]).reshape(-1, 2)
        solved = np.array([self.model.body_translation(values, k) for k, _ in records]).reshape(-1, 2)
        along = np.sum(measured * solved)
        return float(np.sum(measured * measured) / along) if along > 1e-12 else 1.0

    def _landmark_key(self, inc: Increment, which: tuple[str, int], k: int) -> int:
        t_k = inc.t_s
        known = self._landmarks.get(which)
        if known is not None and t_k - known[1] <= self.landmark_lifetime_s:
            key = known[0]
        else:
            self._landmark_count += 1
            key = (L if which[0] == "tag" else R)(self._landmark_count)
            e, n = self.tags[which[1]][:2] if which[0] == "tag" else self.rsus[which[1]]
            factors, point = self.model.landmark(key, e, n)
            self._add(inc, factors)
            inc.values.insert(key, point)
            if not self.anchored:
                self._backlog_landmarks[key] = point
            if self.keep_history:
                self.landmark_positions[key] = np.array([e, n])
        self._landmarks[which] = (key, t_k)
        inc.timestamps[key] = t_k
        return key

    def _landmark_position(self, which: tuple[str, int]) -> tuple[float, float]:
        return self.tags[which[1]][:2] if which[0] == "tag" else self.rsus[which[1]]

    def _move_onto_start(self, start: StartState) -> int:
        """Turn and shift the held track so the keyframe of the start sits on ignition's start state; that keyframe.

        The start state's time may fall up to a keyframe after the keyframe's:
        its position is taken back along its velocity.
        """
        k = min(max(self._nearest_keyframe(start.t_s), 0), self.last_keyframe)
        ref = self.states[k]
        lag = start.t_s - self.keyframe_time(k)
        e, n = start.east_m - start.v_east_mps * lag, start.north_m - start.v_north_mps * lag
        turn = start.yaw_rad - ref.yaw_rad
        for j in list(self.states):
            self.states[j] = self.states[j].moved(ref.east_m, ref.north_m, turn, e, n)
        self.diagnostics["anchor_keyframe"] = k
        return k

    def _release(self, last: Increment | None, start_keyframe: int | None) -> Increment:
        """The held keyframes as one increment, moved onto the start, with the start prior at ``start_keyframe``.

        Without history (fixed-lag) only the keyframes within
        ``release_window_s`` are released: older ones would be marginalised
        at once, and marginalising a long, weakly anchored dead-reckoned
        track is numerically indeterminate.
        """
        merged = Increment(last.keyframe if last else self.last_keyframe, last.t_s if last else self.keyframe_time(self.last_keyframe), anchoring=True)
        window = [inc for inc in self._backlog if inc.t_s >= merged.t_s - self.release_window_s] or self._backlog[-1:]
        allowed = set(self._backlog_landmarks)
        for inc in window:
            allowed.update(self.model.keyframe_keys(inc.keyframe))
            merged.released.append(inc.keyframe)
        first = merged.released[0]
        extra = self.model.first_keyframe_keys(first)  # e.g. the bias node in effect, created before the window
        allowed.update(extra)
        marks = set(self._backlog_landmarks)
        in_window = {id(inc) for inc in window}
        for inc in self._backlog:
            # older increments give only their landmark priors: every held
            # landmark is inserted, and one first seen before the window must
            # keep its prior (else the ranges alone hold it: indeterminate)
            keep = allowed if id(inc) in in_window else marks
            for i in range(inc.factors.size()):
                factor = inc.factors.at(i)
                if all(key in keep for key in factor.keys()):
                    merged.factors.add(factor)
            merged.timestamps.update({key: t for key, t in inc.timestamps.items() if key in allowed})
        for k in merged.released:
            self.model.insert_values(merged.values, k, self.states[k])
        if extra:
            self.model.insert_bias(merged.values, first, self.states[first])
            merged.timestamps.update({key: self.keyframe_time(first) for key in extra})
        for key, point in self._backlog_landmarks.items():
            merged.values.insert(key, point)
            merged.timestamps.setdefault(key, merged.t_s)
        if start_keyframe is not None:
            at = min(max(start_keyframe, merged.released[0]), merged.released[-1])
            st = self._start
            sigma_m = START_PRIOR_INFLATION * st.position_sigma_m
            sigma_yaw = min(START_PRIOR_INFLATION * st.yaw_sigma_rad, math.pi)
            self._add(merged, self.model.prior_factors(at, self.states[at], sigma_m, sigma_yaw))
        self._backlog = []
        self._backlog_landmarks = {}
        self.anchored = True
        return merged
