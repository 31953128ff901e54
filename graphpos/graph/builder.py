"""Turns a measurement stream into keyframes and GTSAM factors.

Keyframes are laid on a regular grid ``t_k = t_0 + k / rate`` from the first
odometry sample of the track (see Gaps below). Keyframe ``k`` is closed when
a measurement arrives after ``t_k``: the wheel/gyro (and IMU) samples up to ``t_k`` are preintegrated into
the odometry factors between ``k - 1`` and ``k``. Every absolute measurement
(tag/RSU range, RSU/GNSS fix, compass yaw) is attached to the keyframe
nearest its own timestamp ``t_s`` — also when it arrives late: a reading for
a keyframe already in the graph goes into the next update, up to
``max_delay_s`` late (issue 6, item 4); later ones are dropped and counted
per channel (``diagnostics["late_dropped"]``).

Start-up (the shared :mod:`graphpos.ignition`): with a start pose from the
user, the drive's first keyframe gets a prior with the user's sigmas. Otherwise keyframes
are held back (no output) and every measurement also goes to ignition,
which solves the start from fixes or ranges with the dead-reckoned motion;
when it gives a start state, the held track is moved rigidly (turned and
shifted) onto it and released to the smoother with a prior at the
keyframe of the start, wide (three times ignition's sigmas: the readings
ignition used are in the graph too) but enough to keep the system
determinate whatever the readings (never IndeterminantLinearSystem). A
drive on which ignition never succeeds gives no output, unless the builder
may solve the held track itself (``solve_unstarted``, graph-batch: offline,
the whole track is there): :meth:`GraphBuilder._start_from_graph`.

Gaps (issue 14, item 3): the odometry is the graph's backbone. A wheel
speed or yaw rate is held (zero-order hold) for at most
``config.max_odometry_gap_s``; keyframes are closed only while every
odometry sensor of the drive is held, so a reading arriving much later
than the odometry (500 s late) no longer conjures keyframes out of
nothing. When a sensor has been silent for longer, the track ends: its
last keyframes are in the graph, readings until the odometry is back are
dropped (``diagnostics["without_odometry"]``), and once every odometry
sensor is back a new track segment starts exactly as the drive did, from a
fresh ignition and its own wide start prior. Nothing ties it to the track
before the gap: over an unobserved minute the vehicle may have gone
anywhere, and a between factor wide enough to say so adds no information,
while one narrow enough to matter would make the covariance lie. Each gap
is listed in ``diagnostics["odometry_gaps"]``. A segment on which ignition
never succeeds leaves nothing in the graph. An accelerometer gap (a
non-finite sample) is held the same way; beyond the hold the inertial
graph integrates zero body acceleration with a wide noise density
(:attr:`~graphpos.graph.models.InertialModel.UNMEASURED_ACCEL_DENSITY`), so
the wheel factor carries the velocity until the accelerometers are back.
Non-finite samples of any sensor are skipped and counted per channel and
field (``diagnostics["non_finite"]``).

Yaw rates are first corrected by the bias seen at standstills so far
(:class:`graphpos.standstill.StandstillGyroBias`, as in the filters), then
by the learnt or given sensor profile (:attr:`GraphBuilder.corrections`),
whose gyro bias is what remains after the standstill correction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, R

from filters.models.angles import wrap_angle
from graphpos.drive import Channel, Drive, Measurement, RowRun
from graphpos.graph.calibration import MIN_NOISE_FIT_DOF
from graphpos.graph.config import GraphConfig
from graphpos.ignition import Ignition, IgnitionConfig, StartPose, StartState, between_walls, rival_gap
from graphpos.profile import SensorProfile
from graphpos.graph.models import GRAVITY_MPS2, KeyframeState, robust
from graphpos.graph.smoothers import ValuesSource
from graphpos.graph.odometry import OdometryDelta, PlanarOdometry
from graphpos.ranging.drive_models import ranges_by_field
from graphpos.standstill import StandstillGyroBias

#: A landmark key is reused for sightings at most this far apart, s.
LANDMARK_LIFETIME_S = 3.0
#: Factor on ignition's sigmas for the start prior of the released track (the whole held track: the
#: readings ignition solved from are in the graph too). A fixed-lag release keeps only the last seconds
#: of the track and its readings, so its prior takes ignition's sigmas: inflated, the wide heading
#: prior was then nearly all the window's heading information, 5600 times weaker than one keyframe's
#: gyro, and GTSAM's Cholesky declared the window indeterminate (it refuses a factor whose consecutive
#: pivots differ by more than 2^12; MRCLAM robots 1 and 4).
START_PRIOR_INFLATION = 3.0
#: The graph starts from a looser heading than a filter (ignition's default
#: 10 degrees): the start only sets the linearisation point and a wide prior,
#: and the graph resolves the heading from every range it holds. On the slow
#: MRCLAM robots, 5 degrees took 100-400 s of driving (10 degrees: robot 1 still 386 s).
START_MAX_YAW_SIGMA_RAD = math.radians(15.0)
#: :meth:`GraphBuilder._start_from_graph`: trial headings, trial positions per heading, and the longest held
#: track it solves, s (48 solves of a 150 s MRCLAM track took 3-18 s CPU; graph-batch on a 290 s synthetic drive
#: took 52 s with it against 2.8 s with ignition starting the track).
GRAPH_START_HEADINGS = 8
GRAPH_START_POSITIONS = 6
GRAPH_START_MAX_TRACK_S = 300.0
#: The odometry sensors: (channel, field) pairs whose silence ends the track.
ODOMETRY_SENSORS = (("imu", "yaw_rate_radps"), ("wheel", "speed_mps"))
_ODOMETRY_FIELD = dict(ODOMETRY_SENSORS)  # one odometry field per channel
_IMU, _WHEEL = ODOMETRY_SENSORS
#: The fields each absolute channel's factors read (checked for finite values).
ABSOLUTE_FIELDS = {"compass": ("yaw_rad",), "gnss": ("east_m", "north_m", "sigma_m"), "rsu": ("sigma_m",)}


@dataclass
class Increment:
    """What one closed keyframe adds to the smoother.

    ``late``: no new keyframe, only the factors of late readings for
    keyframes already in the smoother (of a track that has ended).
    """

    keyframe: int
    t_s: float
    factors: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    values: gtsam.Values = field(default_factory=gtsam.Values)
    timestamps: dict[int, float] = field(default_factory=dict)
    released: list[int] = field(default_factory=list)  # keyframes entering the smoother now
    #: The mean wheel speed of each released keyframe's interval, taken when the increment is made:
    #: the builder forgets old keyframes' speeds (:meth:`GraphBuilder._prune`) while one measurement
    #: closes more keyframes, so a release's older keyframes may be gone from ``GraphBuilder.speeds``
    #: before the increment reaches the smoother.
    speeds: dict[int, float] = field(default_factory=dict)
    anchoring: bool = False  # first information of the trajectory: iterate more
    late: bool = False


@dataclass
class RangeRecord:
    """A range factor's ingredients, kept to rebuild it with another range scale or sigma.

    ``field``: the reading field (``range_m`` or ``rss``) whose range
    model gives the sigma (tag readings), re-evaluated at the estimated
    distance by :meth:`GraphBuilder.reweight_ranges`; None: the sigma came
    with the reading (RSU ranges).
    """

    keyframe: int
    landmark_key: int
    reading_m: float
    sigma_m: float
    field: str | None = None
    #: The landmark's bearing in a camera's image, rad, where the reading has one (a bearing-dependent range error).
    bearing_rad: float = math.nan


@dataclass
class Segment:
    """One track: keyframes ``first`` .. ``last`` on the grid from ``t_s`` (the first keyframe's time)."""

    first: int
    t_s: float
    last: int
    history: tuple[int, ...] = (0, 0, 0, 0, 0)  # sizes of the history lists when it began

    def contains(self, k: int) -> bool:
        return self.first <= k <= self.last

    def nearest(self, t_s: float, period_s: float) -> int:
        """The keyframe of this track's grid nearest ``t_s``."""
        return self.first + int(math.floor((t_s - self.t_s) / period_s + 0.5))


class GraphBuilder:
    """Keyframes and factors from measurements in arrival order.

    Parameters
    ----------
    config : GraphConfig
    model : PlanarModel or InertialModel
    drive : Drive
        Maps only (tags, RSUs) and which channels it has.
    range_models : dict of str to RangeModel
        The range model of each RFID reading field
        (:func:`graphpos.ranging.reading_models`), the estimator's first;
        empty without RFID readings.
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
        How much of the held start-up track is released to the smoother at
        anchoring (its window less a late reading's delay); the history
        keeps all of it.
    scale_ranges_at_start : bool
        Take the ranges' common scale that ignition solves with a start from
        ranges (:meth:`_ignite`).
    """

    def __init__(
        self,
        config: GraphConfig,
        model,
        drive: Drive,
        range_models: dict,
        max_delay_s: float,
        landmark_lifetime_s: float = LANDMARK_LIFETIME_S,
        keep_history: bool = True,
        range_scale: float = 1.0,
        initial_pose: StartPose | None = None,
        release_window_s: float = math.inf,
        scale_ranges_at_start: bool = False,
        solve_unstarted: bool = False,
    ):
        self.config = config
        self.model = model
        self.range_models = dict(range_models)
        self.max_delay_s = max_delay_s
        self.max_gap_s = config.max_odometry_gap_s
        self.landmark_lifetime_s = landmark_lifetime_s
        self.keep_history = keep_history
        self.range_scale = range_scale
        self.scale_ranges_at_start = scale_ranges_at_start
        self.solve_unstarted = solve_unstarted
        self.range_offset_m = 0.0  # subtracted from recorded readings when the graph is rebuilt (graph-batch's offset search)
        self.range_delay_s = 0.0  # how late the tag readings were stamped: their records moved back by it (graph-batch's search)
        self.initial_pose = initial_pose
        self.release_window_s = release_window_s
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
        #: Time of the last finite sample of each odometry sensor the drive has.
        self._last_sample_s = {sensor: -math.inf for sensor in ODOMETRY_SENSORS if drive.has(sensor[0])}
        # IMU preintegration (inertial graph): the held specific force and
        # rate, the samples of the open keyframe interval, the bias to integrate at
        self._preintegrating = model.name == "inertial"
        self._accel_mps2: np.ndarray | None = None
        self._accel_t = -math.inf
        self._gyro_radps: np.ndarray | None = None
        self._imu_t: float | None = None
        self._imu_samples: list[tuple[np.ndarray, np.ndarray, float, bool]] = []
        self._imu_bias: np.ndarray | None = None
        defaults = GraphConfig()
        self._imu_heading_var = defaults.heading_noise_radps_per_sqrt_s**2
        self._imu_turn_scale_var = defaults.turn_scale_density_per_sqrt_s**2
        self._set_imu_turn_noise(c.heading_noise_radps_per_sqrt_s, c.turn_scale_density_per_sqrt_s, c.noise_dof)
        #: The least turn-rate scale density of the IMU factors while the yaw rate's scale is unknown (the estimator
        #: sets it, ``widens_uncalibrated_scales``; a learning that fits the scale clears it); None: the scale is known.
        self.unknown_scale_turn_density: float | None = None
        self.last_keyframe = -1
        self.segments: list[Segment] = []
        self.tracking = False
        self._lost_s: float | None = None  # the last odometry sample of the last track lost
        #: Some keyframe has entered the smoother (the estimator has output).
        self.started = False
        self.anchored = False
        self.states: dict[int, KeyframeState] = {}
        self.speeds: dict[int, float] = {}
        self._waiting: dict[int, list[tuple[str, tuple]]] = {}  # readings for keyframes not closed yet
        self._ready: list[tuple[int, str, tuple]] = []  # readings for closed keyframes, next update
        self._landmarks: dict[tuple[str, int], tuple[int, float]] = {}
        self._landmark_count = 0
        self._backlog: list[Increment] = []
        self._backlog_landmarks: dict[int, np.ndarray] = {}
        self._ignition_args = dict(tags_en_m=np.column_stack([drive.tags.east_m, drive.tags.north_m]), wall_side=drive.tags.wall_side,
                                   has_wheel=drive.has("wheel"),
                                   config=IgnitionConfig(compass_sigma_rad=config.compass_sigma_rad, max_yaw_sigma_rad=START_MAX_YAW_SIGMA_RAD))
        self.ignition: Ignition | None = None  # a fresh one for each track (_begin_segment)
        self._start: StartState | None = None
        #: The yaw-rate bias seen at standstills, taken off every yaw rate first (shared with the filters).
        self.standstill = StandstillGyroBias()
        #: Corrections of the incoming yaw rates and wheel speeds learnt online (:meth:`recalibrate`), after the standstill's.
        self.corrections = SensorProfile()
        # history for batch solves / scale estimation
        self.fixed_factors = gtsam.NonlinearFactorGraph()
        self.range_records: list[RangeRecord] = []
        self.odometry_records: list[tuple[int, OdometryDelta]] = []
        #: (keyframe, compass yaw) of every compass factor, rebuilt by :meth:`graph` with or without the compass bias.
        self.compass_records: list[tuple[int, float]] = []
        #: Prior sigma of the compass bias (rad) :meth:`graph` estimates (:meth:`estimate_compass_bias`); None: the compass factors as built online.
        self.compass_bias_sigma_rad: float | None = None
        self.wheel_scale: float | None = None  # None: wheel factors as built online
        self.wheel_drift_density: float | None = None  # with wheel_scale None: rebuild the drift term at this density
        self.landmark_positions: dict[int, np.ndarray] = {}
        self.diagnostics = {"late_attached": {}, "late_dropped": {}, "without_odometry": {}, "non_finite": {}, "odometry_gaps": [],
                            "ranges": 0, "ranges_unusable": 0, "anchor_keyframe": None, "start": None}
        if initial_pose is not None:
            self.diagnostics["start"] = {"source": "user", **initial_pose.to_dict()}

    @property
    def range_model(self):
        """The estimator's range model (the first of :attr:`range_models`); None without RFID readings."""
        return next(iter(self.range_models.values()), None)

    @property
    def has_tag_ranges(self) -> bool:
        """Whether the drive has tag readings (ranges or RSS) to range from."""
        return bool(self.range_models)

    @property
    def reports_ranges(self) -> bool:
        """Whether the tag readings are ranges (``range_m``), not signal strengths."""
        return getattr(self.range_model, "input_column", None) == "range_m"

    # -- time grid ----------------------------------------------------------
    def _segment_of(self, k: int) -> Segment:
        """The track keyframe ``k`` belongs to."""
        seg = self.segments[-1]  # nearly always: the current track's keyframes are asked for
        if seg.first > k:
            seg = next((s for s in reversed(self.segments) if s.first <= k), self.segments[0])
        return seg

    def keyframe_time(self, k: int) -> float:
        seg = self._segment_of(k)
        return seg.t_s + (k - seg.first) * self.period_s

    def _keyframe_at(self, t_s: float) -> tuple[Segment, int] | None:
        """The segment whose grid holds ``t_s`` and its keyframe nearest ``t_s``; None before the first segment."""
        for seg in reversed(self.segments):
            if t_s >= seg.t_s - 0.5 * self.period_s:
                return seg, seg.nearest(t_s, self.period_s)
        return None

    # -- input ----------------------------------------------------------------
    def add(self, m: Measurement) -> list[Increment]:
        """Take one measurement; return what it completes (closed keyframes, a released track, late readings).

        Keyframes up to the measurement's arrival are closed while the
        odometry covers them (module docstring); a keyframe it no longer
        covers ends the track. A track begins when every odometry sensor
        has a fresh sample: at the drive's first odometry, and after each
        gap. An absolute reading no track covers cannot be placed relative
        to the motion (counted per channel in ``without_odometry``, dropped).
        """
        out = []
        if self.tracking and self.keyframe_time(self.last_keyframe + 1) < m.arrival_s - 1e-9:  # most measurements: the next keyframe is ahead
            out = self._close_covered(m.arrival_s)
            if self.keyframe_time(self.last_keyframe + 1) < m.arrival_s - 1e-9:
                self._lost_s = min(self._last_sample_s.values())
                out += self._end_segment()
        if self._note_odometry(m) and not self.tracking and all(m.t_s - t <= self.max_gap_s for t in self._last_sample_s.values()):
            self._begin_segment(m.t_s)
        return out + self._take(m)

    def flush(self) -> list[Increment]:
        """The drive has ended: close the keyframes still covered up to the last waiting reading, and end the track."""
        if not self.tracking:
            return []
        last = max(self._waiting, default=self.last_keyframe)
        return self._close_covered(self.keyframe_time(last) + 1e-6, ended=True) + self._end_segment()

    def _close_covered(self, until_s: float, ended: bool = False) -> list[Increment]:
        """Close the keyframes before ``until_s`` that every odometry sensor's held sample still covers.

        A sample is held for ``max_gap_s`` while the silence may still turn
        out shorter; once it is known to be longer (``until_s`` beyond the
        hold, or the drive has ``ended``), only the keyframes up to the last
        sample are closed: none is extrapolated past the odometry.
        """
        if self.keyframe_time(self.last_keyframe + 1) >= until_s - 1e-9:
            return []  # the next keyframe is still ahead
        last_s = min(self._last_sample_s.values())
        hold_s = self.max_gap_s if not ended and until_s - last_s <= self.max_gap_s else 0.5 * self.period_s
        covered_s = last_s + hold_s + 1e-9
        closed = []
        while (t := self.keyframe_time(self.last_keyframe + 1)) < until_s - 1e-9 and t <= covered_s:
            closed.append(self._close(self.last_keyframe + 1))
        return closed

    def _note_odometry(self, m: Measurement) -> bool:
        """Record the time of an odometry sample's finite fields (counting non-finite ones); whether it had any."""
        sensor = (m.channel, _ODOMETRY_FIELD.get(m.channel))
        if sensor not in self._last_sample_s or not self._finite(m, sensor[1]):
            return False
        self._last_sample_s[sensor] = m.t_s
        return True

    def _finite(self, m: Measurement, name: str) -> bool:
        """Whether a field of a measurement is finite; a non-finite one is counted in ``non_finite``."""
        if math.isfinite(m.values.get(name, math.nan)):
            return True
        _count(self.diagnostics["non_finite"], f"{m.channel}.{name}")
        return False

    def _take(self, m: Measurement) -> list[Increment]:
        if m.channel == "imu":
            self._take_imu(m)
            return []
        if m.channel == "wheel":
            self._wheel_sample(m.t_s, m.values["speed_mps"])
            return []
        entry = self._entry(m)
        return [] if entry is None else self._place(m, entry)

    def _take_imu(self, m: Measurement) -> None:
        v = m.values
        finite_accel = self._preintegrating and all([self._finite(m, "accel_x_mps2"), self._finite(m, "accel_y_mps2")])
        self._imu_sample(m.t_s, v["yaw_rate_radps"], v["accel_x_mps2"] if finite_accel else None, v["accel_y_mps2"] if finite_accel else None)

    def _imu_sample(self, t_s: float, yaw_rate_radps: float, accel_x_mps2: float | None, accel_y_mps2: float | None) -> None:
        """One IMU sample's step: the held odometry advanced to it, then its yaw rate (if finite) and accelerations (if given) held."""
        if self.tracking:
            self.odometry.advance(t_s)
            if self._preintegrating:
                self._integrate_imu(t_s)
        if math.isfinite(yaw_rate_radps):
            raw = self.standstill.yaw_rate(t_s, yaw_rate_radps)
            yaw_rate = (raw - self.corrections.gyro_bias_radps) / self.corrections.yaw_rate_scale
            self.odometry.set_yaw_rate(yaw_rate)
            if self._preintegrating:
                self._gyro_radps = np.array([0.0, 0.0, yaw_rate])
            if self.tracking and not self.anchored:
                self._ignite(self.ignition.yaw_rate(t_s, yaw_rate))
        if accel_x_mps2 is not None:
            self._accel_mps2 = np.array([accel_x_mps2, accel_y_mps2, GRAVITY_MPS2])
            self._accel_t = t_s

    def _wheel_sample(self, t_s: float, speed_mps: float) -> None:
        """One wheel sample's step: the held odometry advanced to it, then its speed (if finite) held."""
        if self.tracking:
            self.odometry.advance(t_s)
        self.standstill.speed(t_s, speed_mps)
        if math.isfinite(speed_mps):
            speed = speed_mps / self.corrections.wheel_scale
            self.odometry.set_speed(speed)
            if self.tracking and not self.anchored:
                self._ignite(self.ignition.speed(t_s, speed))

    def take_odometry(self, run: RowRun, i: int) -> int:
        """Take IMU and wheel rows of a recorded drive from row ``i`` as :meth:`add` would, up to the first that may close a keyframe.

        Returns the first row not taken: ``i`` itself when row ``i`` needs
        :meth:`add` (no track, a keyframe to close, a non-finite field).
        The rows taken close, begin and end nothing, so each goes straight
        to the sample's own step (:meth:`_imu_sample`, :meth:`_wheel_sample`),
        without a :class:`Measurement` and its checks: the same graph as
        the online loop, a fraction of the Python (issue 19, item 1).
        """
        if not self.tracking:
            return i
        next_s = self.keyframe_time(self.last_keyframe + 1)
        imu_code = run.names.index("imu") if "imu" in run.names else -1
        col = run.columns
        key, t, code = run.key_s, col["t_s"], run.code
        yaw_rate, speed = col.get("yaw_rate_radps"), col.get("speed_mps")
        accel_x, accel_y = (col["accel_x_mps2"], col["accel_y_mps2"]) if self._preintegrating else (None, None)
        last = self._last_sample_s
        isfinite = math.isfinite
        for j in range(i, len(code)):
            if next_s < key[j] - 1e-9:
                return j
            if code[j] == imu_code:
                if not isfinite(yaw_rate[j]) or (accel_x is not None and not (isfinite(accel_x[j]) and isfinite(accel_y[j]))):
                    return j
                self._imu_sample(t[j], yaw_rate[j], None if accel_x is None else accel_x[j], None if accel_y is None else accel_y[j])
                last[_IMU] = t[j]
            else:
                if not isfinite(speed[j]):
                    return j
                self._wheel_sample(t[j], speed[j])
                last[_WHEEL] = t[j]
        return len(code)

    def _entry(self, m: Measurement) -> tuple | None:
        """An absolute reading as a factor entry; None (counted) when it cannot give one."""
        v, ch = m.values, m.channel
        if ch == "rfid":
            if not self.range_models:
                return None
            if (self.corrections.range_offset_m or self.corrections.range_bearing2_m_per_rad2) and "range_m" in v:
                v = self.corrections.corrected_values("rfid", v)  # a camera's bearing term learnt online (graph-isam2)
            distance, sigma, which = ranges_by_field(self.range_models, Channel("rfid", {k: [x] for k, x in v.items()}, validate=False))
            if which[0] < 0:
                _count(self.diagnostics["non_finite"], "rfid." + "/".join(self.range_models))
                return None
            if not (np.isfinite(distance[0]) and np.isfinite(sigma[0]) and sigma[0] > 0):
                self.diagnostics["ranges_unusable"] += 1
                return None
            # the sigma at the reading's own distance stands in until the
            # keyframe's estimate gives a better one (see _range_sigma_m)
            field_name = list(self.range_models)[which[0]]
            return ("range", ("tag", int(v["tag_id"])), float(distance[0]), float(sigma[0]) * self.config.range_sigma_scale, field_name,
                    float(v.get("bearing_rad", math.nan)))
        if ch not in ABSOLUTE_FIELDS or not all([self._finite(m, name) for name in ABSOLUTE_FIELDS[ch]]):
            return None
        if ch == "compass":
            if self.corrections.compass_bias_rad:
                v = self.corrections.corrected_values("compass", v)  # a compass bias learnt online (graph-isam2)
            return ("compass", float(v["yaw_rad"]))
        if ch == "rsu":
            if math.isfinite(v.get("range_m", math.nan)):
                return ("range", ("rsu", int(v["rsu_id"])), float(v["range_m"]), float(v["sigma_m"]), None, math.nan)
            if not all([self._finite(m, "east_m"), self._finite(m, "north_m")]):
                return None
        return ("fix", float(v["east_m"]), float(v["north_m"]), float(v["sigma_m"]))

    def _place(self, m: Measurement, entry: tuple) -> list[Increment]:
        """Attach a reading to the keyframe of its own time: waiting, ready for the next update, a late increment, or dropped (counted)."""
        at = self._keyframe_at(m.t_s)
        current = at is not None and self.tracking and at[0] is self.segments[-1]
        if current and not self.anchored:
            self._ignite_with(m.t_s, entry)  # late or not: ignition places it at its own time
        if m.arrival_s - m.t_s > self.max_delay_s:
            _count(self.diagnostics["late_dropped"], m.channel)
            return []
        if current and at[1] > self.last_keyframe:
            self._waiting.setdefault(at[1], []).append((m.channel, entry))
            return []
        if at is None or not at[0].contains(at[1]):
            _count(self.diagnostics["without_odometry"], m.channel)
            return []
        k = at[1]
        if not self._keyframe_alive(k):
            _count(self.diagnostics["late_dropped"], m.channel)
            return []
        _count(self.diagnostics["late_attached"], m.channel)
        if current:
            self._ready.append((k, m.channel, entry))
            return []
        # a keyframe of a track that has ended: in the smoother, whatever the current track
        inc = Increment(k, self.keyframe_time(k), late=True)
        self._attach(inc, [(k, m.channel, entry)], at_estimate=True)
        return [inc]

    # -- track segments -------------------------------------------------------
    def _begin_segment(self, t_s: float) -> None:
        """A new track from ``t_s`` (the first keyframe's time): a fresh start, as at the drive's beginning."""
        if self._lost_s is not None:
            self.diagnostics["odometry_gaps"].append({"from_s": self._lost_s, "to_s": t_s, "restart": None})
        first = self.last_keyframe + 1
        history = (self.fixed_factors.size(), len(self.range_records), len(self.odometry_records), len(self.compass_records),
                   self.diagnostics["ranges"])
        self.segments.append(Segment(first, t_s, first - 1, history))
        self.model.start_segment(first)
        self.odometry.start(t_s)
        self._imu_t = t_s
        self._imu_samples = []
        self.tracking = True
        self.anchored = self.initial_pose is not None and self._lost_s is None  # the user's pose holds for the drive's start only
        self.ignition = Ignition(**self._ignition_args)
        self._start = None
        self._landmarks = {}

    def _end_segment(self) -> list[Increment]:
        """The track ends (its odometry is lost, or the drive ends).

        Readings waiting for keyframes that will not be closed are dropped
        (``without_odometry``); late readings for closed keyframes go into
        the held track, or, once it is in the smoother, into a late
        increment. A held track is released if ignition, given a last try,
        starts it, else forgotten (its factors leave the history too).
        """
        for entries in self._waiting.values():
            for channel, _ in entries:
                _count(self.diagnostics["without_odometry"], channel)
        self._waiting = {}
        out = []
        if self._ready and self.anchored:
            inc = Increment(self.last_keyframe, self.keyframe_time(self.last_keyframe), late=True)
            self._attach(inc, self._ready, at_estimate=True)
            out.append(inc)
        elif self._ready and self._backlog:
            self._attach(self._backlog[-1], self._ready, at_estimate=False)
        self._ready = []
        if not self.anchored:
            if self._backlog:
                self._ignite(self.ignition.finish())
            if self._start is None and self._backlog and self.solve_unstarted:
                self._ignite(self._start_from_graph())
            if self._start is not None and self._backlog:
                out.append(self._release(None, self._move_onto_start(self._start)))
            else:
                self._discard_segment()
        self.tracking = False
        return out

    def _discard_segment(self) -> None:
        """Forget the current, never started track: its keyframes, its factors in the history and its keyframe numbers."""
        seg = self.segments.pop()
        n_fixed, n_ranges, n_odometry, n_compass, n_range_factors = seg.history
        self.fixed_factors.resize(n_fixed)
        del self.range_records[n_ranges:]
        del self.odometry_records[n_odometry:]
        del self.compass_records[n_compass:]
        self.diagnostics["ranges"] = n_range_factors
        for k in range(seg.first, self.last_keyframe + 1):
            self.states.pop(k, None)
            self.speeds.pop(k, None)
        self.last_keyframe = seg.first - 1
        self._backlog = []
        self._backlog_landmarks = {}

    # -- start-up -------------------------------------------------------------
    def _ignite_with(self, t_s: float, entry: tuple) -> None:
        """Give an absolute reading to ignition (before the track is anchored)."""
        kind = entry[0]
        if kind == "compass":
            state = self.ignition.compass(t_s, entry[1])
        elif kind == "fix":
            state = self.ignition.fix(t_s, entry[1], entry[2], entry[3])
        else:
            _, which, reading, sigma, _, _ = entry
            mark = np.array([self._landmark_position(which)])
            state = self.ignition.ranges(t_s, mark, np.array([reading / self.range_scale]), np.array([sigma / self.range_scale]))
        self._ignite(state)

    def _ignite(self, state: StartState | None) -> None:
        """Take ignition's start state: the drive's start, or (after a gap) the restart of its track.

        A start from ranges that found them read long or short by a common
        scale (:attr:`StartState.range_scale`, kept only when significant)
        scales every range factor from then on, as the filters divide their
        ranges by it, when the ranges are uncalibrated
        (``scale_ranges_at_start``: no range model or profile given; a
        start's short window put a calibrated model's ranges 5 % off on a
        synthetic drive). Only at the drive's start:
        a restart's short window would override what a learning or a
        calibration found since. graph-isam2's learning and graph-batch's
        calibration estimate the scale again; graph-fixed-lag, which learns
        nothing, went from 2.26 to 0.37 m on Plaza1 (UWB ranges 7 % long).
        """
        if state is not None and self._start is None:
            self._start = state
            if self.diagnostics["start"] is None:
                self.diagnostics["start"] = state.describe()
                if self.scale_ranges_at_start:
                    self.range_scale *= state.range_scale
            else:
                self.diagnostics["odometry_gaps"][-1]["restart"] = state.describe()

    def recalibrate(self, corrections: SensorProfile, range_scale: float, range_model) -> None:
        """Use learnt corrections from now on: readings still to come are corrected, new factors get the noise levels.

        ``corrections``: the yaw-rate and wheel corrections (of raw readings)
        and noise levels; ``range_scale`` and ``range_model`` (a sigma) for
        tag ranges still to come (of the field the model reads). Factors
        already built stay as they are.
        """
        self.corrections = corrections
        self.range_scale = range_scale
        if range_model is not None:
            self.range_models[range_model.input_column] = range_model
        o = self.odometry
        if corrections.heading_noise_radps_per_sqrt_s is not None:
            o.heading_var = corrections.heading_noise_radps_per_sqrt_s**2
        if corrections.turn_scale_density_per_sqrt_s is not None:  # fitted with the scale (calibration.fit_profile)
            o.turn_scale_var = corrections.turn_scale_density_per_sqrt_s**2
            self.unknown_scale_turn_density = None
        self._set_imu_turn_noise(corrections.heading_noise_radps_per_sqrt_s, corrections.turn_scale_density_per_sqrt_s,
                                 corrections.source.get("noise_dof"))

    def widen_unknown_wheel_scale(self, density_per_sqrt_s: float) -> None:
        """Wheel factors built from now on take at least this wheel-scale density (a wheel whose scale is unknown)."""
        self.odometry.scale_var = max(self.config.wheel_scale_density_per_sqrt_s, density_per_sqrt_s) ** 2

    def _keyframe_alive(self, k: int) -> bool:
        return k in self.states

    def _set_imu_turn_noise(self, heading_density: float | None, turn_scale_density: float | None, dof: float | None) -> None:
        """The heading noise and turn-rate scale densities the IMU factors add to the gyro's (inertial graph), as the
        planar odometry adds them to its turn; only from a noise fit that determined them (``GraphConfig.noise_dof``)."""
        if dof is not None and dof < MIN_NOISE_FIT_DOF:
            return  # a guess: the gyro's own figure and the defaults stay
        if heading_density is not None:
            self._imu_heading_var = heading_density**2
        if turn_scale_density is not None:
            self._imu_turn_scale_var = turn_scale_density**2

    def _imu_turn_noise_var(self) -> float:
        """The open interval's yaw-rate variance density beyond the gyro's white noise (rad^2/s) at its mean squared
        yaw rate (:meth:`InertialModel.preintegrate`; :class:`PlanarOdometry`'s ``heading_density`` and
        ``turn_scale_density`` terms)."""
        duration_s = sum(dt for _, _, dt, _ in self._imu_samples)
        yaw_rate2 = sum(rate[2] ** 2 * dt for _, rate, dt, _ in self._imu_samples) / duration_s if duration_s > 0 else 0.0
        turn_scale_var = self._imu_turn_scale_var
        if self.unknown_scale_turn_density is not None:
            turn_scale_var = max(turn_scale_var, self.unknown_scale_turn_density**2)
        return self._imu_heading_var + turn_scale_var * yaw_rate2

    def _integrate_imu(self, t_s: float) -> None:
        """Hold the last IMU sample up to ``t_s``: one preintegration step of the open interval.

        The accelerometers' sample is held for at most ``max_odometry_gap_s``;
        after that the step integrates zero body acceleration and is marked
        unmeasured (:meth:`InertialModel.preintegrate` widens its noise).
        """
        dt = t_s - self._imu_t
        if self._gyro_radps is not None and dt > 0:
            measured = self._accel_mps2 is not None and self._imu_t - self._accel_t <= self.max_gap_s
            force = self._accel_mps2 if measured else np.array([0.0, 0.0, GRAVITY_MPS2])
            self._imu_samples.append((force, self._gyro_radps, dt, measured))
        if dt > 0 or self._gyro_radps is None:
            self._imu_t = t_s

    # -- keyframes ------------------------------------------------------------
    def _initial_state(self) -> KeyframeState:
        """A track's first keyframe: the user's start pose, else the origin heading east (moved onto ignition's start later)."""
        p = self.initial_pose if self.anchored else None
        e, n, yaw = (p.east_m, p.north_m, p.yaw_rad) if p is not None else (0.0, 0.0, 0.0)
        v = self.odometry.speed_mps
        return KeyframeState(float(e), float(n), float(yaw), v * math.cos(yaw), v * math.sin(yaw))

    def _close(self, k: int) -> Increment:
        t_k = self.keyframe_time(k)
        inc = Increment(k, t_k)
        seg = self.segments[-1]
        delta = self.odometry.cut(t_k)
        if self._preintegrating:
            self._integrate_imu(t_k)
        entries = self._waiting.pop(k, [])
        if k == seg.first:
            state = self._initial_state()
            inc.anchoring = self.anchored
            if self.anchored:
                p = self.initial_pose
                self._add(inc, self.model.prior_factors(k, state, p.position_sigma_m, p.yaw_sigma_rad))
        else:
            pim = self.model.preintegrate(self._imu_samples, self._imu_bias, self._imu_turn_noise_var()) if self._preintegrating else None
            state = self.model.predict(self.states[k - 1], delta, pim)
            wheel, *others = self.model.odometry_factors(k, delta, pim)
            inc.factors.add(wheel)
            if self.keep_history:
                self.odometry_records.append((k, delta))
            self._add(inc, others)
        self._imu_samples = []
        self._imu_bias = state.bias
        self.states[k] = state
        self.speeds[k] = delta.mean_speed_mps
        self.model.insert_values(inc.values, k, state)
        for key in self.model.keyframe_keys(k):
            inc.timestamps[key] = t_k
        self._add(inc, self.model.keyframe_factors(k, state))
        self.last_keyframe = seg.last = k
        ready = [(k, channel, e) for channel, e in entries] + self._ready
        self._ready = []
        if not self.anchored:
            self._backlog.append(inc)
            self._attach(inc, ready, at_estimate=False)
            if self._start is None:
                self._prune(k)
                return inc
            return self._release(inc, self._move_onto_start(self._start))
        self._attach(inc, ready, at_estimate=True)
        inc.released = [k]
        inc.speeds[k] = self.speeds[k]
        self.started = True
        self._prune(k)
        return inc

    def _prune(self, k: int) -> None:
        """Forget states no late reading can refer to (fixed-lag memory stays flat).

        Kept: those within ``max_delay_s`` of the newest, and of the keyframes
        one measurement may close at once (up to ``max_odometry_gap_s`` of them).
        """
        if self.keep_history or not self.anchored:
            return
        old = k - int(math.ceil((max(self.max_delay_s, self.max_gap_s) + 1.0) / self.period_s)) - 1
        self.states.pop(old, None)
        self.speeds.pop(old, None)

    def _add(self, inc: Increment, factors: list) -> None:
        for f in factors:
            inc.factors.add(f)
            if self.keep_history:
                self.fixed_factors.add(f)

    # -- absolute measurements ------------------------------------------------
    def _attach(self, inc: Increment, ready: list[tuple[int, str, tuple]], at_estimate: bool) -> None:
        """Factors of readings for closed keyframes; ``at_estimate``: their keyframes' states are the smoother's."""
        c = self.config
        for k, _, entry in ready:
            kind = entry[0]
            if kind == "compass":
                inc.factors.add(self.model.compass_factor(k, entry[1], c.compass_sigma_rad))
                if self.keep_history:
                    self.compass_records.append((k, entry[1]))
            elif kind == "fix":
                _, e, n, s = entry
                dim = self.model.fix_dim()
                sig = np.array([s, s, 1e3]) if dim == 3 else s
                self._add(inc, [self.model.fix_factor(k, e, n, robust(sig, c, dim))])
            else:
                _, which, reading, sigma, field_name, bearing = entry
                key = self._landmark_key(inc, which, k)
                if field_name is not None and at_estimate and k in self.states:
                    s, (e, n) = self.states[k], self._landmark_position(which)
                    at = float(self._range_sigma_m(np.array([math.hypot(s.east_m - e, s.north_m - n) * self.range_scale]), field_name)[0])
                    sigma = at if math.isfinite(at) else sigma
                if self.keep_history:
                    self.range_records.append(RangeRecord(k, key, reading, sigma, field_name, bearing))
                noise = robust(sigma / self.range_scale, c)
                inc.factors.add(self.model.range_factor(k, key, reading / self.range_scale, noise))
                self.diagnostics["ranges"] += 1

    def _range_sigma_m(self, distance_m: np.ndarray, field_name: str) -> np.ndarray:
        """The sigma of the range model of a reading field at estimated distances (times ``range_sigma_scale``).

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
        sigma = np.asarray(self.range_models[field_name].predict_sigma_m(np.asarray(distance_m, dtype=np.float64)), dtype=np.float64)
        return np.where(np.isfinite(sigma) & (sigma > 0), sigma * self.config.range_sigma_scale, np.nan)

    def reweight_ranges(self, values: gtsam.Values) -> None:
        """Re-evaluate every tag range's sigma at the distance of a solved trajectory (``keep_history``)."""
        records = [r for r in self.range_records if r.field is not None]
        if not records:
            return
        pos = np.array([self.model.position(values, r.keyframe) for r in records])
        marks = np.array([self.landmark_positions[r.landmark_key] for r in records])
        distance = np.hypot(*(pos - marks).T) * self.range_scale
        fields = np.array([r.field for r in records])
        sigma = np.full(len(records), np.nan)
        for name in set(fields.tolist()):
            sigma[fields == name] = self._range_sigma_m(distance[fields == name], name)
        for r, s in zip(records, sigma):
            if np.isfinite(s):
                r.sigma_m = float(s)

    def correct_range_records(self, offset: float, bearing2: float) -> None:
        """Correct the recorded tag readings as a learnt correction corrects those to come:
        ``reading - bearing2 * bearing^2 - offset`` (the bearing term where a reading has one), at least 0."""
        for r in self.range_records:
            if r.field is not None:
                b = r.bearing_rad if math.isfinite(r.bearing_rad) else 0.0
                r.reading_m = max(r.reading_m - bearing2 * b * b - offset, 0.0)

    def correct_compass_records(self, bias_rad: float) -> None:
        """Correct the recorded compass readings as a learnt compass bias corrects those to come: ``reading - bias``."""
        self.compass_records = [(k, wrap_angle(yaw - bias_rad)) for k, yaw in self.compass_records]

    def range_factor(self, record: RangeRecord, scale: float, offset: float = 0.0):
        """Rebuild a recorded range factor for another range scale and offset: ``(reading - offset) / scale``."""
        noise = robust(record.sigma_m / scale, self.config)
        return self.model.range_factor(record.keyframe, record.landmark_key, (record.reading_m - offset) / scale, noise)

    def delayed_range_records(self, delay_s: float) -> list[RangeRecord]:
        """The range records with each tag reading moved to the keyframe nearest ``delay_s`` before its own (a
        reading stamped ``delay_s`` after it was taken), at most to its track's first or last keyframe: every
        reading stays (a delay search that dropped those moved off their track would find a spurious delay in the
        error they no longer add). RSU ranges (no ``field``) keep theirs."""
        if delay_s == 0.0:
            return list(self.range_records)
        out = []
        for r in self.range_records:
            if r.field is None:
                out.append(r)
                continue
            seg = self._segment_of(r.keyframe)
            k = seg.nearest(self.keyframe_time(r.keyframe) - delay_s, self.period_s)
            out.append(replace(r, keyframe=min(max(k, seg.first), seg.last, self.last_keyframe)))
        return out

    def graph(self, scale: float | None = None, extra_turn_density2: float = 0.0, offset: float | None = None,
              range_records: list[RangeRecord] | None = None) -> gtsam.NonlinearFactorGraph:
        """Every factor so far (``keep_history``): ranges (``range_records``, else :attr:`range_records`) built
        with ``scale`` and ``offset`` (reading units; else :attr:`range_offset_m`), wheel factors with
        :attr:`wheel_scale` (else with the drift term at :attr:`wheel_drift_density`, else as built online),
        their heading loosened by ``extra_turn_density2`` (:meth:`OdometryDelta.with_turn_density`),
        compass factors with the compass bias as an unknown when :attr:`compass_bias_sigma_rad` is set
        (its prior: zero +- that sigma; :meth:`estimate_compass_bias`)."""
        scale = self.range_scale if scale is None else scale
        offset = self.range_offset_m if offset is None else offset
        g = gtsam.NonlinearFactorGraph(self.fixed_factors)
        for r in self.range_records if range_records is None else range_records:
            g.add(self.range_factor(r, scale, offset))
        sigma = self.config.compass_sigma_rad
        if self.compass_bias_sigma_rad is not None and self.compass_records:
            g.add(self.model.compass_bias_prior(self.compass_bias_sigma_rad)[0])
            for k, yaw in self.compass_records:
                g.add(self.model.compass_bias_factor(k, yaw, sigma))
        else:
            for k, yaw in self.compass_records:
                g.add(self.model.compass_factor(k, yaw, sigma))
        for k, delta in self.odometry_records:
            if self.wheel_scale is None and self.wheel_drift_density is not None:
                delta = delta.with_drift_density(self.wheel_drift_density)
            if extra_turn_density2 > 0:
                delta = delta.with_turn_density(extra_turn_density2)
            g.add(self.model.wheel_factor(k, delta, self.wheel_scale))
        return g

    def estimate_compass_bias(self, sigma_rad: float | None, values: gtsam.Values) -> gtsam.Values:
        """From now on :meth:`graph` carries the compass bias (prior zero +- ``sigma_rad``; None: it no longer does);
        ``values`` with the compass frame added at zero bias where the graph has it and they do not."""
        from graphpos.graph.models import COMPASS_BIAS_KEY

        self.compass_bias_sigma_rad = sigma_rad
        if sigma_rad is None or not self.compass_records or values.exists(COMPASS_BIAS_KEY):
            return values
        out = gtsam.Values(values)
        out.insert(COMPASS_BIAS_KEY, self.model.compass_bias_prior(sigma_rad)[1])
        return out

    def history_values(self, recent: gtsam.Values) -> gtsam.Values:
        """Values of every variable of :meth:`graph`: ``recent``'s, else the causal ones.

        ``recent`` is a windowed smoother's estimate (its window, and what it
        marginalised as it left); variables it never held (marginalised on
        arrival) take the state read at their keyframe's update
        (:attr:`states`), landmarks their map position.
        """
        values = gtsam.Values(recent)
        for k in sorted(self.states):
            if values.exists(self.model.pose_key(k)):
                continue
            keyframe = gtsam.Values()  # its pose, velocity and bias node: those not already there
            self.model.insert_values(keyframe, k, self.states[k])
            for known in [key for key in keyframe.keys() if values.exists(key)]:
                keyframe.erase(known)
            values.insert(keyframe)
        for key in self.fixed_factors.keyVector():
            if values.exists(key):
                continue
            symbol = gtsam.Symbol(key)
            if chr(symbol.chr()) in "lr":
                values.insert(key, self.model.landmark(key, *self.landmark_positions[key])[1])
            else:  # a bias node a track's first keyframe shares with the keyframes before it
                self.model.insert_bias(values, int(symbol.index()), self.states[int(symbol.index())])
        return values

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
        """The landmark variable of a sighting: the landmark's key of its last sighting within
        ``landmark_lifetime_s``, else a fresh key with its prior. A late increment (for a track
        that has ended) takes fresh keys and leaves the current track's landmarks alone."""
        t_k = inc.t_s
        known = None if inc.late else self._landmarks.get(which)
        if known is not None and t_k - known[1] <= self.landmark_lifetime_s:
            key = known[0]
        else:
            self._landmark_count += 1
            key = (L if which[0] == "tag" else R)(self._landmark_count)
            e, n = self.tags[which[1]][:2] if which[0] == "tag" else self.rsus[which[1]]
            factors, point = self.model.landmark(key, e, n)
            self._add(inc, factors)
            inc.values.insert(key, point)
            if not (self.anchored or inc.late):
                self._backlog_landmarks[key] = point
            if self.keep_history:
                self.landmark_positions[key] = np.array([e, n])
        if not inc.late:
            self._landmarks[which] = (key, t_k)
        inc.timestamps[key] = t_k
        return key

    def _landmark_position(self, which: tuple[str, int]) -> tuple[float, float]:
        return self.tags[which[1]][:2] if which[0] == "tag" else self.rsus[which[1]]

    def _start_from_graph(self) -> StartState | None:
        """The start of a held track ignition never started, from the track's own graph (offline); None when it does not determine one.

        Ignition solves a start from a minute of readings placed by dead
        reckoning, each loosened by the dead-reckoning error since it
        (:class:`~graphpos.ignition.IgnitionConfig`); a robot that creeps and
        turns, seeing a landmark or two at a time (MRCLAM: 5-9 m in 150 s,
        turning 5-15 rad), may not be determined so within the minute, and
        6 of the 30 MRCLAM6 pieces of 150 s never started. The held track's
        own factors (odometry with its noise model, every range) do not lose
        that information: the track is moved rigidly to
        :data:`GRAPH_START_HEADINGS` headings times :data:`GRAPH_START_POSITIONS`
        places on the circle of its last range, each solved by
        Levenberg-Marquardt. As ignition: the best plausible solution is the
        start when every distinct one (its ``ambiguity_m`` / ``ambiguity_yaw_rad``)
        has an error at least ``chi2_margin / 2`` higher, and its marginal
        sigmas are under ignition's limits, at the track's keyframe whose
        heading is best determined (one of 12 spread over it). The planar
        graph only (the inertial one would need its bias nodes). A held track
        longer than :data:`GRAPH_START_MAX_TRACK_S` is solved on its last
        that many seconds (the factors among their keyframes), and, when
        they do not determine a start, on each such piece before them in
        turn: the start may fall anywhere on the track, which is then moved
        onto it whole. MRCLAM6 robot 1 with every range of each second
        minute left out never started (its 60 s of ranges at a time, at
        ignition's default range sigmas, left 20-50 degrees of heading);
        on its last 300 s the track gives a start. What it found goes to
        ``diagnostics["graph_start"]`` (one entry per piece it tried).
        """
        seg = self.segments[-1]
        if self.model.name != "planar":
            return None
        piece = max(int(GRAPH_START_MAX_TRACK_S / self.period_s), 1)
        last = self.last_keyframe
        while last > seg.first:
            start = self._start_from_piece(max(seg.first, last - piece), last)
            if start is not None:
                return start
            last -= piece
        return None

    def _start_from_piece(self, first: int, last_k: int) -> StartState | None:
        """:meth:`_start_from_graph` on the held track's keyframes ``first`` to ``last_k``."""
        records = [r for r in self.range_records
                   if first <= r.keyframe <= last_k and r.landmark_key in self._backlog_landmarks]
        if len(records) < 3:
            return None
        said = self.diagnostics.setdefault("graph_start", [])
        c = self._ignition_args["config"]
        keys = {self.model.pose_key(k) for k in range(first, last_k + 1)} | set(self._backlog_landmarks)
        graph = gtsam.NonlinearFactorGraph()
        for inc in self._backlog:
            for i in range(inc.factors.size()):
                factor = inc.factors.at(i)
                if factor is not None and all(key in keys for key in factor.keys()):
                    graph.push_back(factor)
        landmarks = gtsam.Values()
        for key, point in self._backlog_landmarks.items():
            landmarks.insert(key, point)
        last = records[-1]
        mark = np.asarray(self._backlog_landmarks[last.landmark_key])
        ref = self.states[last.keyframe]
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.batch_max_iterations)
        params.setRelativeErrorTol(1e-5)
        solutions = []
        for a in np.linspace(0.0, 2.0 * math.pi, GRAPH_START_POSITIONS, endpoint=False):
            e, n = mark + last.reading_m / self.range_scale * np.array([math.cos(a), math.sin(a)])
            for yaw in np.linspace(-math.pi, math.pi, GRAPH_START_HEADINGS, endpoint=False):
                values = gtsam.Values(landmarks)
                for k in range(first, last_k + 1):
                    self.model.insert_values(values, k, self.states[k].moved(ref.east_m, ref.north_m, yaw - ref.yaw_rad, e, n))
                try:
                    solved = gtsam.Values(gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize())
                except RuntimeError:
                    continue
                error = graph.error(solved)
                if math.isfinite(error):
                    solutions.append((error, solved))
        walls = (self._ignition_args["tags_en_m"], self._ignition_args["wall_side"])
        solutions = [(err, v) for err, v in solutions if not len(walls[0]) or between_walls(np.array(self.model.position(v, last.keyframe)), *walls)]
        if not solutions:
            said.append({"t_s": self.keyframe_time(first), "result": "no plausible solution"})
            return None
        solutions.sort(key=lambda sol: sol[0])
        poses = [(*self.model.position(v, last.keyframe), self.model.yaw(v, last.keyframe), error) for error, v in solutions]
        gap = rival_gap(poses[0], poses[1:], c)
        if gap is not None:  # a turned or shifted track fits almost as well
            said.append({"t_s": self.keyframe_time(first), "result": "ambiguous", "error_gap": gap})
            return None
        best = solutions[0][1]
        try:
            marginals = gtsam.Marginals(graph, best)
            candidates = sorted({int(k) for k in np.linspace(first, last_k, 12)} | {last.keyframe})
            covs = {k: marginals.marginalCovariance(self.model.pose_key(k)) for k in candidates}
        except RuntimeError:
            said.append({"t_s": self.keyframe_time(first), "result": "not determinate"})
            return None
        k = min(covs, key=lambda j: covs[j][2, 2])
        state = self.model.read(ValuesSource(best), k, self.speeds.get(k, 0.0))
        position = self.model.position_cov(covs[k], state)
        sigma_p, sigma_yaw = math.sqrt(max(position[0, 0], position[1, 1])), math.sqrt(covs[k][2, 2])
        within = sigma_p <= c.max_position_sigma_m and sigma_yaw <= c.max_yaw_sigma_rad
        said.append({"t_s": self.keyframe_time(first), "result": "started" if within else "sigmas over ignition's limits",
                     "position_sigma_m": sigma_p, "yaw_sigma_rad": sigma_yaw})
        if not within:
            return None
        return StartState(self.keyframe_time(k), state.east_m, state.north_m, state.yaw_rad, self.speeds.get(k, 0.0), sigma_p, sigma_yaw,
                          c.speed_sigma_mps, "graph")

    def _move_onto_start(self, start: StartState) -> int:
        """Turn and shift the held track (the current segment) so the keyframe of the start sits on ignition's start state; that keyframe.

        The start state's time may fall up to a keyframe after the keyframe's:
        its position is taken back along its velocity.
        """
        seg = self.segments[-1]
        k = min(max(seg.nearest(start.t_s, self.period_s), seg.first), self.last_keyframe)
        ref = self.states[k]
        lag = start.t_s - self.keyframe_time(k)
        e, n = start.east_m - start.v_east_mps * lag, start.north_m - start.v_north_mps * lag
        turn = start.yaw_rad - ref.yaw_rad
        for j in range(seg.first, self.last_keyframe + 1):
            self.states[j] = self.states[j].moved(ref.east_m, ref.north_m, turn, e, n)
        if self.diagnostics["anchor_keyframe"] is None:
            self.diagnostics["anchor_keyframe"] = k
        return k

    def _release(self, last: Increment | None, start_keyframe: int | None) -> Increment:
        """The held keyframes as one increment, moved onto the start, with the start prior at ``start_keyframe``.

        Only the keyframes within ``release_window_s`` are released to the
        smoother (the history keeps them all): older ones would be marginalised
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
            merged.speeds[k] = self.speeds[k]
        if extra:
            self.model.insert_bias(merged.values, first, self.states[first])
            merged.timestamps.update({key: self.keyframe_time(first) for key in extra})
        for key, point in self._backlog_landmarks.items():
            merged.values.insert(key, point)
            merged.timestamps.setdefault(key, merged.t_s)
        if start_keyframe is not None:
            at = min(max(start_keyframe, merged.released[0]), merged.released[-1])
            st = self._start
            # inflated when the held track's readings, ignition's, are in the graph too;
            # a window drops those before it, and with them most of the heading information
            inflation = START_PRIOR_INFLATION if len(window) == len(self._backlog) else 1.0
            sigma_m = inflation * st.position_sigma_m
            sigma_yaw = min(inflation * st.yaw_sigma_rad, math.pi)
            self._add(merged, self.model.prior_factors(at, self.states[at], sigma_m, sigma_yaw))
        self._backlog = []
        self._backlog_landmarks = {}
        self.anchored = self.started = True
        return merged


def _count(counts: dict[str, int], key: str) -> None:
    """One more of ``key`` in a diagnostics count."""
    counts[key] = counts.get(key, 0) + 1

