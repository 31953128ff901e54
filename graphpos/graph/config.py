"""Configuration of the factor-graph estimators.

Every tunable of the graph backend lives here, with its unit in its name.
Sensor noise defaults are song2016 §6 (IMU 1-sigma 0.1 m/s^2 and 0.2 deg/s
at 100 Hz); the paper gives no wheel-speed or compass figure, so those are
typical automotive values, documented beside each field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from graphpos.errors import ConfigError
from graphpos.estimator import require_valid_numbers
from graphpos.ignition import MAX_ODOMETRY_GAP_S

PARAMETERISATIONS = ("auto", "planar", "inertial")
ROBUST_LOSSES = ("huber", "cauchy", "none")
RANGE_SCALE_MODES = ("auto", "off", "estimate")
WHEEL_SCALE_MODES = ("off", "estimate")
COMPASS_BIAS_MODES = ("off", "estimate")
RANGE_OFFSET_MODES = ("auto", "off", "estimate")
RANGE_DELAY_MODES = ("auto", "off", "estimate")
#: IMU and wheel rate, Hz, a graph assumes when its config leaves them to the drive and the drive has no such rows.
DEFAULT_SENSOR_RATE_HZ = 100.0


@dataclass
class GraphConfig:
    """Tunables of the GTSAM estimators (``graph-batch``, ``graph-isam2``, ``graph-fixed-lag``).

    Parameters
    ----------
    keyframe_rate_hz : float
        Keyframes (= output epochs) per second.
    parameterisation : {"auto", "planar", "inertial"}
        ``planar``: Pose2 keyframes, wheel + gyro preintegrated into relative
        poses. ``inertial``: Pose3 + velocity + IMU bias with GTSAM's
        combined IMU preintegration. ``auto``: inertial when the drive has
        accelerometers, planar otherwise.
    robust_loss : {"huber", "cauchy", "none"}
        M-estimator on range, RSU and GNSS factors.
    robust_k : float
        The M-estimator's threshold, in units of the measurement's sigma.
    compass_loss : {"huber", "cauchy", "none"}, compass_robust_k : float
        M-estimator of the compass yaw and its threshold (in sigmas).
    range_sigma_scale : float
        Factor on the range model's 1-sigma of every tag range. A tag's
        RSS shadowing is persistent, so its readings' errors repeat; as
        independent factors they would count several times (song2016's
        filters use the same kind of factor, ``range_sigma_scale``).
    accel_sigma_mps2, gyro_sigma_radps : float
        Per-sample 1-sigma of the accelerometers and the yaw gyro at
        ``imu_rate_hz`` (song2016 §6: 0.1 m/s^2, 0.2 deg/s).
    imu_rate_hz : float or None
        IMU rate, to turn per-sample sigmas into noise densities. None (the
        default): measured on the drive (1 / the median interval of its IMU
        rows; :data:`DEFAULT_SENSOR_RATE_HZ` without them). A rate given is
        kept: for a logger that repeats each reading over several rows,
        give the rate of new readings (``graphpos info`` warns of such a
        channel and prints it).
    accel_bias_sigma_mps2, gyro_bias_sigma_radps : float
        Prior 1-sigma of the turn-on biases.
    accel_bias_walk_mps2_per_sqrt_s, gyro_bias_walk_radps_per_sqrt_s : float
        Bias random walks (inertial graph).
    wheel_speed_sigma_mps : float
        Per-sample 1-sigma of the wheel speed (no figure in the papers).
    wheel_scale_density_per_sqrt_s : float
        Relative wheel-speed error density (1/sqrt(s)) for the wheel's
        scale error: along-track variance grows by ``(density * v)^2`` per
        second, whatever the wheel rate (see :class:`~graphpos.graph.odometry.PlanarOdometry`).
    heading_noise_radps_per_sqrt_s : float
        White heading noise density beyond the gyro's (rad/sqrt(s)), whatever
        the sample rate; about none by default, graph-batch's
        self-calibration sets it from the residuals (a sensor profile).
    turn_scale_density_per_sqrt_s : float
        Relative turn-rate error density (1/sqrt(s)): heading variance grows
        by ``(density * yaw_rate)^2`` per second (a turn-rate scale error,
        :class:`~graphpos.graph.odometry.PlanarOdometry`). 0.02: a gyro's
        scale is good to a per cent or two; graph-batch estimates the
        drive's own (:mod:`graphpos.graph.calibration`).
    uncalibrated_turn_scale_density_per_sqrt_s : float
        Inertial graph: the least turn-rate scale density of the IMU
        factors while the yaw rate's scale is unknown: until graph-isam2's
        online learning has fitted it (a learning over
        :data:`~graphpos.graph.calibration.MIN_TURN_FOR_SCALE_RAD` of
        turning), throughout where no sensor profile with a fitted scale is
        given and nothing learns one (graph-fixed-lag; graph-isam2 with
        ``learn_online`` off; graph-batch with ``self_calibrate`` off), not
        in graph-batch's self-calibration
        (:attr:`~graphpos.graph.estimators.GraphBatch.widens_uncalibrated_scales`).
        A yaw rate whose scale is known to about 15 % (the error
        class real sensor sets show goes to 30 %) is off by 0.15 of each
        turn; over a turn of about 16 s that is a density of
        ``0.15 sqrt(16) = 0.6``. With the default 0.02 the heading followed
        a yaw rate 21 % off through the first U-turn of a realistic drive,
        40 degrees from the compass, before any learning had seen a turn.
        On realistic 300 s drives, seeds 0-19, graph-isam2's mean RMS went
        from 0.335 to 0.213 m (0.3: 0.219, 1.0: 0.212; seed 11 2.64 to
        0.28 m, no seed worse by over 0.01 m); ideal paper drives 0.360 to
        0.363 m, paper profile 3.029 to 3.023 m. Not the planar graph:
        there MRCLAM6's mean went from 0.392 to 0.510 m and Plaza1's from
        0.325 to 0.381 m (no compass, and ranges that see the heading
        poorly: the odometry's turns carry it).
    uncalibrated_wheel_scale_density_per_sqrt_s : float
        The least wheel-scale density of the wheel factors of a graph that
        is given no sensor profile and learns none (graph-fixed-lag;
        graph-isam2 with ``learn_online`` off; graph-batch with
        ``self_calibrate`` off): the wheel's scale is unknown. A scale known
        to about 5 % (the error class real sensor sets show goes to 10 %)
        over about 16 s between tags: ``0.05 sqrt(16) = 0.2``; the default
        0.12 allows about 3 %. graph-fixed-lag on realistic 300 s drives
        (wheels up to 10 % off): mean RMS 0.645 to 0.471 m on seeds 0-3,
        0.723 to 0.570 m on seeds 4-19 (0.4: 0.469 and 0.514 m), fresh
        seeds 20-29 0.687 to 0.513 m; Plaza1 0.373 to 0.360 m; paper
        profile (wheels 3.5-5.5 % off) 3.035 to 3.046 m; where the wheel is
        exact it costs: ideal paper drives 0.385 to 0.429 m, MRCLAM6
        (wheels within 1.2 %) 0.924 to 0.965 m. graph-isam2's first
        learning fits the scale
        (:attr:`~graphpos.graph.estimators.GraphIsam2.learns_online`).
    noise_dof : float or None
        Degrees of freedom of the noise fit behind ``heading_noise_radps_per_sqrt_s``
        and ``turn_scale_density_per_sqrt_s`` when a sensor profile set them
        (:meth:`~graphpos.profile.SensorProfile.tuned`); None: configured.
        The inertial graph's IMU factor takes those two only from a fit that
        determined them (:data:`~graphpos.graph.calibration.MIN_NOISE_FIT_DOF`),
        else the defaults: its gyro's white noise is a sensor figure, better
        than a guess (the planar graph has no such figure and takes the
        guess). On the simulator's 76 s straight drives (dof 0, a fitted
        heading noise 35 times the gyro's) graph-batch's RMS on ideal
        paper-straight seed 0 went from 0.25 to 0.50 m with the guess.
    batch_wheel_drift_factor : float
        ``graph-batch`` with ``wheel_scale="estimate"``: the first batch
        solve, the one the wheel scale is fitted to, uses
        ``wheel_scale_density_per_sqrt_s`` times this factor. Looser than
        online: online, the wheel must carry the vehicle from one tag to
        the next, while the fit needs a trajectory that follows the ranges,
        not the wheel's scale error. A multiple, not a value of its own, so
        a wheel declared exact (a tiny density) stays exact. Measured over 8
        seeds of paper-straight / paper-comprehensive (optimized layout):
        density 0.12 (factor 1) gave 0.385 / 0.367 m RMS, 0.25 gave
        0.359 / 0.302, 0.4 gave 0.613 / 0.302 (too loose: the along-track
        position then wanders between tags).
    wheel_rate_hz : float or None
        Wheel-speed rate (per-sample sigma -> density); None: measured on
        the drive, as ``imu_rate_hz``.
    lateral_slip_sigma_mps : float
        1-sigma of the body's lateral (and vertical) velocity: the
        non-holonomic constraint of the wheel odometry factor.
    heading_drift_sigma_radps : float
        Extra heading uncertainty per second of the wheel + gyro odometry
        (an unmodelled gyro bias in the planar graph). 0.1 deg/s keeps
        graph-batch's NEES in its 95 % band (0.2 made it conservative).
    compass_sigma_rad : float
        1-sigma of a compass yaw (no figure in the papers; 1.5 degrees:
        with the Cauchy loss's threshold of 0.45 sigma (0.7 degree),
        graph-batch's NEES stays inside its 95 % band and a 20-degree
        deflection is ridden through; 2 degrees with a 0.5-sigma threshold
        was conservative). The threshold: the simulated compass has
        disturbances of 5 degrees over several seconds (steel structures),
        and at 10 Hz even down-weighted readings add up; over 12 seeds of
        paper-straight / paper-comprehensive, a threshold of 0.667 sigma gave
        graph-batch 0.402 / 0.439 m RMS (one drive with a 6-degree
        disturbance at the curve: 1.88 m), 0.45 gave 0.370 / 0.306 m and
        graph-isam2 0.608 / 0.559 m; 0.3 gave graph-batch 0.359 / 0.275 m
        but graph-isam2 0.648 / 0.637 m (online, the heading then follows
        the gyro too long after a real turn).
    max_delay_s : float
        A range/RSU reading arriving up to this late is attached to the
        keyframe of its own timestamp; later ones are dropped (counted per
        channel in ``diagnostics["late_dropped"]``).
    max_odometry_gap_s : float
        An odometry sensor (wheel speed, yaw rate; the accelerometers of the
        inertial graph) silent for up to this long is held at its last
        sample. A longer silence of the wheel or the gyro ends the track: the
        graph starts again, from a fresh start-up, once both are back
        (:mod:`graphpos.graph.builder`); one of the accelerometers leaves
        the inertial graph on the wheel until they are back. 2 s: the MRCLAM
        robots' odometry pauses for up to 1.03 s.
    fixed_lag_s : float
        Smoother lag of ``graph-fixed-lag``, s. Keyframes are marginalised
        once per ``smoothers.MARGINALISE_EVERY_S`` (1 s), so the window
        holds between ``fixed_lag_s`` and ``fixed_lag_s`` + 1 s.
    isam2_window_s : float
        ``graph-isam2`` (and ``graph-batch``'s seeding pass) keeps the
        keyframes of this many seconds in its iSAM2; older ones are marginalised (their information stays as a
        prior on the rest), so its per-update cost stays flat on long drives
        (:class:`~graphpos.graph.smoothers.WindowedIsam2Smoother`). Its causal
        output is the same as with the whole history wherever readings
        older than this no longer move the present (a few tag spacings or
        odometry gaps back). Its learning and ``final`` solves use the whole
        history, kept by the estimator, not this window.
    final : bool
        ``graph-isam2`` only: return the smoothed trajectory at the end
        instead of the causal one.
    output_covariance : bool
        Compute the east/north covariance of each output.
    range_scale : {"auto", "off", "estimate"}
        ``graph-batch``: ``estimate`` self-calibrates a common range scale
        (``reading = scale * distance``) in an outer loop
        (:mod:`graphpos.graph.calibration`); ``auto`` (default) does so when
        no range model is given and the drive reports ranges (a ranging
        radio's scale is unknown until calibrated: Plaza's reads 7 % long),
        and, in graph-batch, when its ranges come from RSS (a reader on the
        vehicle hearing a few dB weaker than the calibration stand's reads
        every distance long by a common factor: on paper-profile drives,
        mean RMS over seeds 0-2 0.84 to 0.49 m on paper-comprehensive, 1.08
        to 0.54 m on paper-imm; ideal drives 0.28 to 0.26-0.27 m; CPU +35-50 %).
    range_scale_bounds : tuple of float
        Search interval of the scale.
    range_offset : {"auto", "off", "estimate"}
        ``graph-batch`` only. ``estimate``: the final solve searches the
        offset common to every reported range by profile likelihood
        (:func:`~graphpos.graph.calibration.estimate_range_offset`) and adds
        the offset's uncertainty to the output covariances. ``auto``: so it
        does when graph-batch self-calibrates or is given a sensor profile
        (the offset the profile has not removed, e.g. another vehicle's
        camera: MRCLAM6 robots 3, 2, 4, 5 with robot 1's profile, RMS
        0.143/0.169/0.284/0.174 to 0.123/0.154/0.239/0.160 m, ANEES
        10.1/8.6/18.8/7.6 to 3.9/4.1/6.3/5.2; with their own profiles
        robot 4's ANEES 12.2 to 7.5; Plaza1 unchanged; on 150 s pieces with
        a profile from the drive's first half, median ANEES 4.0 to 2.6 but
        mean RMS 0.207 to 0.227 m: a short piece pins the offset down
        poorly). ``off``: never.
    range_delay : {"auto", "off", "estimate"}
        ``graph-batch`` only. ``estimate``: the final solve searches by
        profile likelihood how long after it was taken each tag reading was
        stamped (a reader that reports a round as it ends, a logger's
        latency; :func:`~graphpos.graph.calibration.estimate_range_delay`)
        and moves the readings back by it. ``auto``: its self-calibration
        turns it on for its final solve (its first, with loosened odometry,
        hardly tells a delay from a track that lags) when the drive has wheel
        speed (without one, the IMU's velocity absorbs a shift of the readings
        in time), and puts what it finds
        in the profile
        (``range_delay_s``), which corrects the readings' times for every
        estimator.
    compass_bias : {"off", "estimate"}
        ``graph-batch``, and ``graph-isam2``'s online learning: a learnt bias
        corrects the readings to come once significant and found again by
        the next learning
        (:meth:`~graphpos.graph.estimators.GraphIsam2._confirmed_compass_bias`;
        applied at once, 15-30 s of history put 0.2-0.6 degrees of bias on
        unbiased compasses, ideal paper-straight's RMS went from 0.37 to
        0.42 m, and a GNSS multipath episode left a 3.8-degree bias). Paper
        profile, mean RMS: paper-straight seeds 0-3 2.33 to 2.18 m, fresh
        seeds 10-13 2.55 to 2.48 m, paper-comprehensive 1.97 to 1.91 m,
        long-tunnel 7.69 to 3.72 m; ideal and realistic drives unchanged.
        ``estimate`` (default): graph-batch's solves carry the
        compass's bias (``reading = yaw + bias``: a compass deviated by its
        installation, the car's own steel) as one unknown shared by every
        compass reading, with a prior of zero +- ``compass_bias_sigma_rad``
        (:meth:`~graphpos.graph.builder.GraphBuilder.graph`). A constant
        deviation of a degree or two, taken as white noise, holds the heading
        off by as much over every reading, and the track drifts sideways
        between tags (paper-profile drives, 1.5-2.5 degrees: RMS 1.0-2.7 m
        against 0.3-0.6 m with the deviation removed). The ranges and fixes
        make it observable; without them the prior alone bounds it.
    compass_bias_sigma_rad : float
        1-sigma of that prior (default 5 degrees).
    wheel_scale : {"off", "estimate"}
        ``graph-batch`` only. ``estimate``: self-calibrate the wheel's
        scale error (``reading = scale * speed``) from the drive: fit it to
        the causal pass (whose wheel factors carry the drift term), then
        solve with corrected readings and white wheel noise only.
    wheel_scale_bounds : tuple of float
        Limits of the wheel scale.
    batch_max_iterations : int
        Levenberg-Marquardt iteration limit of ``graph-batch``.
    self_calibrate : bool
        ``graph-batch`` without a sensor profile: a first solve, with
        odometry noise loosened by ``calibration_odometry_factor`` so the
        trajectory follows the ranges and fixes, gives the drive's sensor
        profile (gyro bias, turn-rate and wheel scales, range scale, offset
        and sigma, noise levels: :func:`~graphpos.graph.calibration.fit_profile`);
        the second solve uses it. Its ``diagnostics["profile"]`` is what
        ``graphpos calibrate`` saves.
    learn_online : bool
        ``graph-isam2`` without a sensor profile: learn one online from the
        causal history and correct the readings still to come
        (:class:`~graphpos.graph.estimators.GraphIsam2`).
    covariance_check : bool
        ``graph-isam2`` and ``graph-fixed-lag``: widen the causal
        covariances by how far the causal rows turned out from the
        smoother's later estimate of them (``_check_covariance`` in
        :mod:`graphpos.graph.estimators`); False: the model's covariance as
        it is.
    calibration_odometry_factor : float
        Factor on the heading noise densities (``heading_drift_sigma_radps``,
        ``turn_scale_density_per_sqrt_s``) of the first solve.
    """

    keyframe_rate_hz: float = 10.0
    parameterisation: str = "auto"
    robust_loss: str = "huber"
    robust_k: float = 1.345
    range_sigma_scale: float = 1.5
    compass_loss: str = "cauchy"
    compass_robust_k: float = 0.45
    accel_sigma_mps2: float = 0.1
    gyro_sigma_radps: float = math.radians(0.2)
    imu_rate_hz: float | None = None
    accel_bias_sigma_mps2: float = 0.1
    gyro_bias_sigma_radps: float = math.radians(0.5)
    accel_bias_walk_mps2_per_sqrt_s: float = 1e-2
    gyro_bias_walk_radps_per_sqrt_s: float = 1e-3
    wheel_speed_sigma_mps: float = 0.1
    wheel_scale_density_per_sqrt_s: float = 0.12
    heading_noise_radps_per_sqrt_s: float = 1e-4
    turn_scale_density_per_sqrt_s: float = 0.02
    uncalibrated_turn_scale_density_per_sqrt_s: float = 0.6
    uncalibrated_wheel_scale_density_per_sqrt_s: float = 0.2
    noise_dof: float | None = None
    batch_wheel_drift_factor: float = 2.0
    wheel_rate_hz: float | None = None
    lateral_slip_sigma_mps: float = 0.05
    heading_drift_sigma_radps: float = math.radians(0.1)
    compass_sigma_rad: float = math.radians(1.5)
    max_delay_s: float = 3.0
    max_odometry_gap_s: float = MAX_ODOMETRY_GAP_S
    fixed_lag_s: float = 10.0
    isam2_window_s: float = 120.0
    final: bool = False
    output_covariance: bool = True
    range_scale: str = "auto"
    range_scale_bounds: tuple[float, float] = (0.8, 1.25)
    range_offset: str = "auto"
    range_delay: str = "auto"
    compass_bias: str = "estimate"
    compass_bias_sigma_rad: float = math.radians(5.0)
    wheel_scale: str = "estimate"
    wheel_scale_bounds: tuple[float, float] = (0.8, 1.25)
    batch_max_iterations: int = 100
    self_calibrate: bool = True
    learn_online: bool = True
    covariance_check: bool = True
    calibration_odometry_factor: float = 5.0

    def __post_init__(self) -> None:
        if self.parameterisation not in PARAMETERISATIONS:
            raise ConfigError(f"parameterisation must be one of {PARAMETERISATIONS}, got {self.parameterisation!r}")
        for name in ("robust_loss", "compass_loss"):
            if getattr(self, name) not in ROBUST_LOSSES:
                raise ConfigError(f"{name} must be one of {ROBUST_LOSSES}, got {getattr(self, name)!r}")
        if self.compass_bias not in COMPASS_BIAS_MODES:
            raise ConfigError(f"compass_bias must be one of {COMPASS_BIAS_MODES}, got {self.compass_bias!r}")
        if self.wheel_scale not in WHEEL_SCALE_MODES:
            raise ConfigError(f"wheel_scale must be one of {WHEEL_SCALE_MODES}, got {self.wheel_scale!r}")
        if self.range_scale not in RANGE_SCALE_MODES:
            raise ConfigError(f"range_scale must be one of {RANGE_SCALE_MODES}, got {self.range_scale!r}")
        if self.range_offset not in RANGE_OFFSET_MODES:
            raise ConfigError(f"range_offset must be one of {RANGE_OFFSET_MODES}, got {self.range_offset!r}")
        if self.range_delay not in RANGE_DELAY_MODES:
            raise ConfigError(f"range_delay must be one of {RANGE_DELAY_MODES}, got {self.range_delay!r}")
        require_valid_numbers(self, skip=("max_delay_s",))
        for name in ("imu_rate_hz", "wheel_rate_hz"):
            rate = getattr(self, name)
            if rate is not None and not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
                raise ConfigError(f"{name} must be a positive finite number or None (measured on the drive), got {rate!r}")
        if not (math.isfinite(self.max_delay_s) and self.max_delay_s >= 0):
            raise ConfigError(f"max_delay_s must be >= 0, got {self.max_delay_s}")
        for name in ("fixed_lag_s", "isam2_window_s"):
            if getattr(self, name) <= self.max_delay_s + 2.0 / self.keyframe_rate_hz:
                raise ConfigError(
                    f"{name} ({getattr(self, name)}) must exceed max_delay_s ({self.max_delay_s}) by at least two keyframes, "
                    "or late readings would refer to keyframes already marginalised"
                )
        lo, hi = self.range_scale_bounds
        if not (0 < lo < 1 < hi):
            raise ConfigError(f"range_scale_bounds must bracket 1, got {self.range_scale_bounds}")


@dataclass
class RangesConfig:
    """Tunables of ``graph-ranges`` (ranges only, constant-velocity prior; :mod:`graphpos.graph.ranges`).

    Parameters
    ----------
    accel_psd_m2ps3 : float
        Power spectral density of the white acceleration of the
        constant-velocity prior on each axis, m^2/s^3
        (:func:`filters.models.vehicle.white_acceleration_noise`). Over
        paper-straight seeds 0-4, in the tunnel: 0.03 gave 0.47 m RMS (dense
        layout) and 0.72 m (optimized), ANEES 1.3 / 1.6; 0.1 gave 0.53 /
        1.00 m and on the optimized layout two drives with keyframes
        behind a wall (ANEES 6-7); 0.3 gave 1.15 m on the optimized layout.
    robust_loss : {"huber", "cauchy", "none"}, robust_k : float
        M-estimator of the range factors and its threshold (in sigmas), as
        :class:`GraphConfig`.
    range_sigma_scale : float
        Factor on the range model's 1-sigma of every tag range (as
        :class:`GraphConfig`: a tag's shadowing repeats from reading to reading).
    gate_sigmas : float
        The causal pass that gives the smoother its initial values skips a
        range whose innovation exceeds this many sigmas.
    batch_max_iterations : int
        Levenberg-Marquardt iteration limit.
    output_covariance : bool
        Marginal east/north covariance of each output.
    epoch_s : float
        Readings taken within this long after an epoch's first reading
        belong to that epoch (one keyframe, at the first reading's time).
        Readings of one scan may be logged milliseconds apart (MRCLAM's
        landmarks of one camera frame: 1 ms; its scans are 0.1 s and more
        apart, the simulated drives' RFID scans a second); a keyframe per
        reading made the system ill-conditioned (:func:`graphpos.graph.ranges._epochs`).
        At 20 m/s, 10 ms moves the vehicle 0.2 m, well inside a range's sigma.
    """

    accel_psd_m2ps3: float = 0.03
    robust_loss: str = "huber"
    robust_k: float = 1.345
    range_sigma_scale: float = 1.5
    gate_sigmas: float = 3.5
    batch_max_iterations: int = 100
    output_covariance: bool = True
    epoch_s: float = 0.01

    def __post_init__(self) -> None:
        if self.robust_loss not in ROBUST_LOSSES:
            raise ConfigError(f"robust_loss must be one of {ROBUST_LOSSES}, got {self.robust_loss!r}")
        require_valid_numbers(self)
