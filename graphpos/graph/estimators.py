"""The odometry factor-graph estimators: ``graph-isam2``, ``graph-fixed-lag`` (and its smoothed output), ``graph-batch``.

All of them share the keyframe/factor builder (:mod:`graphpos.graph.builder`)
and the Estimator contract: ``run(drive)`` is ``start`` + ``process`` of every
measurement in arrival order + ``finish``.

- ``graph-isam2``: one iSAM2 update per keyframe with that keyframe's new
  factors and values only; the output row of keyframe ``k`` is the estimate
  right after its update, i.e. from data received up to ``t_k`` (causal).
  Its iSAM2 holds the last ``config.isam2_window_s`` of keyframes, so the
  per-update cost stays flat on long drives; the estimator keeps every
  factor, and ``config.final`` returns the smoothed trajectory of the whole
  drive from them instead.
- ``graph-fixed-lag``: the same with GTSAM's IncrementalFixedLagSmoother
  (``config.fixed_lag_s``); per-update cost and memory stay flat.
  ``graph-fixed-lag-smoothed`` outputs each keyframe from the same
  smoother just before it leaves the window (a lag late).
- ``graph-batch``: Levenberg–Marquardt over the whole drive, initialised
  from the iSAM2 pass, with marginal covariances of every output position;
  ``config.range_scale = "estimate"`` self-calibrates the range scale
  (:mod:`graphpos.graph.calibration`).
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from typing import Any

import gtsam
import numpy as np

from graphpos.drive import Drive, Measurement
from graphpos.errors import ConfigError, EstimationError, MissingChannelError
from graphpos.estimate import Estimate, OutputRow
from graphpos.estimator import Estimator
from graphpos.graph.builder import ODOMETRY_SENSORS, GraphBuilder, Increment
from graphpos.graph.config import DEFAULT_SENSOR_RATE_HZ, GraphConfig
from graphpos.graph.models import COMPASS_BIAS_KEY, KeyframeState, make_model
from graphpos.graph.smoothers import MARGINALISE_EVERY_S, FixedLagSmoother, ValuesSource, WindowedIsam2Smoother, gtsam_error
from graphpos.ignition import NOT_STARTED
from graphpos.ranging.drive_models import reading_models

#: Extra (relinearising) iSAM2 updates when the start-up backlog is released.
ANCHOR_ITERATIONS = 4

_CHANNELS = ("imu", "wheel", "compass", "rfid", "rsu", "gnss")


class _GraphEstimator(Estimator):
    """Shared online machinery: builder + incremental smoother + output rows."""

    #: Odometry between fixes: an IMU or wheel speed.
    required_any = (("imu", "wheel"),)
    optional_channels = _CHANNELS

    @classmethod
    def default_config(cls) -> GraphConfig:
        return GraphConfig()

    def __init__(self, config: Any = None, layout: str | None = None, range_model: Any = None, initial_pose: Any = None, profile: Any = None):
        super().__init__(config, layout, range_model, initial_pose, profile)
        if not isinstance(self.config, GraphConfig):
            raise ConfigError(f"{self.name} takes a GraphConfig, got {type(self.config).__name__}")

    #: ``range_scale="auto"`` also scales ranges from RSS (a reader weaker than the calibration stand's).
    #: graph-batch only: searched at each online learning, it doubled graph-isam2's CPU on paper-profile
    #: drives (2.6 to 6.1 s on paper-straight) for 0.02-0.19 m of mean RMS.
    scales_rss_ranges = False

    # -- hooks ------------------------------------------------------------------
    def _make_smoother(self, model_name: str):
        return WindowedIsam2Smoother(model_name, self.config.isam2_window_s)

    def _builder_options(self) -> dict[str, Any]:
        return {"max_delay_s": self.config.max_delay_s, "release_window_s": self._release_window_s(self.config.isam2_window_s)}

    def _release_window_s(self, window_s: float) -> float:
        """How much of the held start-up track to release into a smoother of this window: what it keeps
        for at least a late reading's delay (:meth:`GraphBuilder._release`)."""
        return window_s - self.config.max_delay_s - 1.0 / self.config.keyframe_rate_hz

    #: Whether the causal rows' covariances are checked against the smoother's later estimate of them
    #: (:meth:`_check_covariance`; ``config.covariance_check`` turns it off).
    checks_covariance = False

    #: Whether odometry that repeats its readings is counted by its new readings, not its rows, where the
    #: config leaves the rate to the drive (:func:`_with_drive_rates`). graph-batch only; see :class:`GraphBatch`.
    counts_new_readings = False

    #: Whether the inertial graph's IMU factors take the turn-rate scale density of an uncalibrated yaw rate
    #: (``config.uncalibrated_turn_scale_density_per_sqrt_s``) unless a sensor profile with a fitted scale is given
    #: (graph-isam2's learning gives one online), and the wheel factors that of an uncalibrated wheel
    #: (``config.uncalibrated_wheel_scale_density_per_sqrt_s``) unless a sensor profile is given or the estimator
    #: learns one online (:attr:`learns_online`). Off in the solves of graph-batch's self-calibration
    #: (:meth:`GraphBatch._calibration_solve`).
    widens_uncalibrated_scales = True

    @property
    def learns_online(self) -> bool:
        """Whether it fits a sensor profile to the data received so far, as it runs (graph-isam2's learning)."""
        return False

    # -- online ---------------------------------------------------------------
    def start(self, drive: Drive) -> None:
        range_models = reading_models(drive, self.resolved_range_model(drive), self.name) if drive.has("rfid") else {}
        self.config = _with_drive_rates(self.config, drive, self.counts_new_readings)
        self.model = make_model(self.config, drive.has_accelerometers, drive.has("wheel"))
        if self.model.name == "inertial" and not drive.has_accelerometers:
            raise MissingChannelError(f"{self.name}: the inertial graph needs accelerometers; drive '{drive.name}' has none (use parameterisation='planar')")
        if self.model.name == "planar" and not drive.has("wheel"):
            # without a speed the planar graph (no velocity state) holds each keyframe where the last range put it:
            # on a 5 m/s synthetic drive, causal RMS 14 m with a claimed 0.6 m
            raise MissingChannelError(f"{self.name}: the planar graph needs wheel speed (it has no velocity of its own); drive "
                                      f"'{drive.name}' has none: use accelerometers (parameterisation='inertial') or graph-ranges")
        uncalibrated = self.config.range_scale == "estimate" or (
            self.config.range_scale == "auto" and self.range_model is None and self.profile is None)
        self.builder = GraphBuilder(self.config, self.model, drive, range_models, initial_pose=self.start_pose(drive),
                                    scale_ranges_at_start=uncalibrated, **self._builder_options())
        if self.widens_uncalibrated_scales and (self.profile is None or self.profile.turn_scale_density_per_sqrt_s is None):
            # the yaw rate's scale is unknown until a fit over enough turning (graph-isam2's learning) finds it
            self.builder.unknown_scale_turn_density = self.config.uncalibrated_turn_scale_density_per_sqrt_s
        if self.widens_uncalibrated_scales and self.profile is None and not self.learns_online:  # and the wheel's
            self.builder.widen_unknown_wheel_scale(self.config.uncalibrated_wheel_scale_density_per_sqrt_s)
        self.smoother = self._make_smoother(self.model.name)
        self.rows: list[OutputRow] = []
        self.update_times_s: list[float] = []
        self._drive_name = drive.name
        self._unchecked: collections.deque[tuple[int, float, float, np.ndarray, KeyframeState]] = collections.deque()  # rows not yet checked
        self._checked: collections.deque[tuple[float, float]] = collections.deque()  # (t_s, d' (P - S)^-1 d) of the checked rows
        self._next_check_s = -math.inf
        self._covariance_scale = 1.0
        self._scales: list[float] = []
        # the same, checked COVARIANCE_CHECK_EARLY_LAG_S after them, until the rows above set the factor
        self._unchecked_early: collections.deque[tuple[int, float, float, np.ndarray, KeyframeState]] = collections.deque()
        self._checked_early: collections.deque[tuple[float, float]] = collections.deque()

    def process(self, measurement: Measurement) -> list[OutputRow]:
        return self._apply(self.builder.add(measurement))

    def _process_recorded(self, drive: Drive) -> None:
        """:meth:`Estimator._process_recorded` with the odometry rows between keyframes taken as arrays.

        Each run of IMU and wheel rows goes to :meth:`process` one row at
        a time only where a row may close a keyframe (or needs the
        row-by-row path); the rows between are taken at once
        (:meth:`GraphBuilder.take_odometry`): the same graph and output as
        the online loop, without Python per sample (issue 19, item 1).
        """
        for item in drive.feed(self.channels_used(drive), by=self.merge_by, runs_of=tuple(c for c, _ in ODOMETRY_SENSORS)):
            if isinstance(item, Measurement):
                self.process(item)
                continue
            i = 0
            while i < len(item):
                self.process(item.measurement(i))
                i = self.builder.take_odometry(item, i + 1)

    def _apply(self, increments: list[Increment]) -> list[OutputRow]:
        """Update the smoother with each released (or late) increment; a row per new keyframe once started (none before)."""
        out = []
        for inc in increments:
            if inc.late:
                self._update(inc)
            elif inc.released:
                self._update(inc)
                out.append(self._row(inc.keyframe))
        self.rows.extend(out)
        if out and (self._unchecked or self._unchecked_early):
            k = self.builder.last_keyframe  # every closed keyframe is in the smoother now
            if self.builder.keyframe_time(k) >= self._next_check_s:
                self._check_covariance(k)
                self._next_check_s = self.builder.keyframe_time(k) + self._check_timing_s()[1]
        return out

    def _check_timing_s(self) -> tuple[float, float]:
        """(lag, period) of the covariance check, s: a row is checked once this much later data has come, every period."""
        return COVARIANCE_CHECK_LAG_S, COVARIANCE_CHECK_EVERY_S

    def _check_covariance(self, k: int) -> None:
        """Scale the causal covariances to come by how far recent rows departed from the smoothed track.

        Each causal row (one per :data:`COVARIANCE_CHECK_SPACING_S`) is
        compared, once :data:`COVARIANCE_CHECK_LAG_S` of later data has
        come, with the smoother's present estimate of its keyframe (no truth
        is read). For a consistent model the difference ``d`` of the causal
        estimate (covariance ``P``) and the smoothed one (``S``) has
        covariance ``P - S`` (the smoothed error is uncorrelated with the
        difference), so ``d' (P - S)^-1 d`` averages 2 (east, north) and,
        where the true errors are ``a`` times the model's covariance, ``2 a``
        (:func:`difference_nees`). The mean over the rows checked in the
        last :data:`COVARIANCE_CHECK_WINDOW_S`, halved, is the factor (at
        least 1) on the covariances output until the next check (every
        :data:`COVARIANCE_CHECK_EVERY_S`): an a posteriori variance factor.
        The model's covariance holds only the noise it knows of; on the
        MRCLAM robots (odometry from commanded speeds, camera range errors
        that persist for seconds) the causal rows were 3-7 times further off
        than their ellipses said (ANEES 22-110). Measured against ``P``
        alone (which ignores what the smoothed estimate shares with the
        row, and understates the factor) the check left ANEES 4.9-14.1;
        against ``P - S``, 2.1-9.1 (Plaza1 1.03, simulated drives with a
        consistent model unchanged; ``benchmarks/real_drives.py -e
        graph-isam2``). Until :data:`COVARIANCE_CHECK_MIN_ROWS` rows have
        been checked that late, the rows checked
        :data:`COVARIANCE_CHECK_EARLY_LAG_S` after them set the factor. The
        factor only widens.
        """
        cutoff_s = self.builder.keyframe_time(k) - self._check_timing_s()[0]
        self._differences(self._unchecked, cutoff_s, self._checked)
        while self._checked and self._checked[0][0] < cutoff_s - COVARIANCE_CHECK_WINDOW_S:
            self._checked.popleft()
        if self._unchecked_early:
            self._differences(self._unchecked_early, self.builder.keyframe_time(k) - COVARIANCE_CHECK_EARLY_LAG_S, self._checked_early)
        if len(self._checked) >= COVARIANCE_CHECK_MIN_ROWS:
            self._covariance_scale = max(1.0, float(np.mean([x for _, x in self._checked])) / 2.0)
            self._unchecked_early.clear()
        elif len(self._checked_early) >= COVARIANCE_CHECK_MIN_ROWS:
            self._covariance_scale = max(1.0, float(np.mean([x for _, x in self._checked_early])) / 2.0)
        self._scales.append(self._covariance_scale)

    def _differences(self, unchecked: collections.deque, cutoff_s: float, checked: collections.deque) -> None:
        """Take the rows of ``unchecked`` up to ``cutoff_s`` and put each one's :func:`difference_nees` in ``checked``."""
        ready = []
        while unchecked and self.builder.keyframe_time(unchecked[0][0]) <= cutoff_s:
            ready.append(unchecked.popleft())
        source = self.smoother.source()
        for k_row, east_m, north_m, causal, state in ready:
            key = self.model.pose_key(k_row)
            if not self.smoother.holds(key):
                continue
            try:
                now = self.model.read(source, k_row, 0.0, with_bias=False)  # the one keyframe, not the window's every value
                # the marginal's body frame turned by the row's yaw (the builder of a fixed-lag smoother keeps no old states)
                smoothed = self.model.position_cov(self.smoother.marginal(key), state)
            except RuntimeError as exc:
                raise gtsam_error(exc, f"{self.name}: smoothed estimate of keyframe {k_row}") from None
            q = difference_nees(np.array([east_m - now.east_m, north_m - now.north_m]), causal, smoothed)
            if math.isfinite(q):
                checked.append((self.builder.keyframe_time(k_row), q))

    def _estimates_range_scale(self) -> bool:
        """Whether to self-calibrate the range scale: ``range_scale`` "estimate", or "auto" with
        tag ranges and no range model given (graph-batch offline, graph-isam2 online): reported ranges,
        and for graph-batch (:attr:`scales_rss_ranges`) ranges from RSS too."""
        mode = self.config.range_scale
        ranges = self.builder.reports_ranges or (self.scales_rss_ranges and self.builder.has_tag_ranges)
        return mode == "estimate" or (mode == "auto" and self.range_model is None and ranges)

    def _update(self, inc: Increment) -> None:
        t = time.perf_counter()
        try:
            self.smoother.update(inc.factors, inc.values, inc.timestamps, ANCHOR_ITERATIONS if inc.anchoring else 0)
        except RuntimeError as exc:
            raise gtsam_error(exc, f"{self.name} on '{self._drive_name}', keyframe {inc.keyframe} (t = {inc.t_s:.2f} s)") from None
        if not inc.late:
            k = inc.keyframe
            self.builder.states[k] = self.model.read(self.smoother.source(), k, inc.speeds[k])
        self.update_times_s.append(time.perf_counter() - t)

    def _row(self, k: int, state: KeyframeState | None = None) -> OutputRow:
        """Keyframe ``k``'s output row: ``state`` (default: the one read at its update) and its marginal,
        scaled by the last covariance check's factor where the estimator checks (:meth:`_check_covariance`)."""
        state = self.builder.states[k] if state is None else state
        cov = None
        if self.config.output_covariance:
            try:
                cov = self.model.position_cov(self.smoother.marginal(self.model.pose_key(k)), state)
            except RuntimeError as exc:
                raise gtsam_error(exc, f"{self.name}: marginal covariance of keyframe {k}") from None
        row = _output_row(self.builder.keyframe_time(k), state, cov)
        if cov is None or not (self.checks_covariance and self.config.covariance_check):
            return row
        if not self._unchecked or row.t_s - self.builder.keyframe_time(self._unchecked[-1][0]) >= COVARIANCE_CHECK_SPACING_S:
            self._unchecked.append((k, row.east_m, row.north_m, cov, state))
            if COVARIANCE_CHECK_EARLY_LAG_S < self._check_timing_s()[0] and len(self._checked) < COVARIANCE_CHECK_MIN_ROWS:
                self._unchecked_early.append((k, row.east_m, row.north_m, cov, state))
        if self._covariance_scale == 1.0:
            return row
        return dataclasses.replace(row, cov_en_m2=cov * self._covariance_scale)

    def finish(self) -> Estimate:
        self._apply(self.builder.flush())
        return self._estimate(self.rows)

    def _estimate(self, rows: list[OutputRow]) -> Estimate:
        times = np.asarray(self.update_times_s) if self.update_times_s else np.zeros(1)
        if not self.builder.started:
            ignition = self.builder.ignition
            self.builder.diagnostics["not_started"] = ignition.not_started() if ignition is not None else NOT_STARTED
        standstill = self.builder.standstill
        diagnostics = {
            **self.builder.diagnostics,
            **({"standstill": standstill.describe()} if standstill.standstills else {}),
            "parameterisation": self.model.name,
            "keyframes": self.builder.last_keyframe + 1,
            "update_ms_mean": float(times.mean() * 1e3),
            "update_ms_p95": float(np.percentile(times, 95) * 1e3),
            "update_ms_max": float(times.max() * 1e3),
            "range_scale": self.builder.range_scale,
        }
        if self._scales:
            scales = np.asarray(self._scales)
            diagnostics["covariance_scale"] = {"checks": int(scales.size), "mean": float(scales.mean()), "max": float(scales.max()),
                                               "last": float(scales[-1])}
        return Estimate.from_rows(self.name, rows, rate_hz=self.config.keyframe_rate_hz, diagnostics=diagnostics)


def _with_drive_rates(config: GraphConfig, drive: Drive, new_readings: bool = False) -> GraphConfig:
    """The config with ``imu_rate_hz`` / ``wheel_rate_hz`` measured from the drive where it leaves them None.

    Sensor sigmas are per sample; their noise densities need the real
    sample rate (the Plaza odometry runs at 5 Hz, the simulator at 100 Hz):
    1 / the median interval of the channel's rows, or
    :data:`~graphpos.graph.config.DEFAULT_SENSOR_RATE_HZ` when the drive has
    too few (a live feed starts with none). A rate the config gives is kept.

    ``new_readings``: a channel that repeats its readings over several rows
    (drive check ``held-readings``, :func:`~graphpos.io.checks.held_readings`)
    gets the rate of its new readings instead: a repeated reading repeats
    its error, and counted once per row it would make the sensor several
    times more precise than it is.
    """
    rates = {}
    for channel, field_name in (("imu", "imu_rate_hz"), ("wheel", "wheel_rate_hz")):
        if getattr(config, field_name) is not None:
            continue
        rates[field_name] = DEFAULT_SENSOR_RATE_HZ
        if drive.has(channel) and len(drive.channels[channel]) > 2:
            dt = float(np.median(np.diff(drive.channels[channel].t_s)))
            if dt > 0:
                rates[field_name] = 1.0 / dt
    if new_readings:
        from graphpos.io.checks import held_readings

        rates.update({setting: new_hz for _, _, setting, _, new_hz in held_readings(drive) if setting in rates})
    return dataclasses.replace(config, **rates) if rates else config


def _output_row(t_s: float, state: KeyframeState, cov: np.ndarray | None) -> OutputRow:
    return OutputRow(t_s, state.east_m, state.north_m, state.v_east_mps, state.v_north_mps, state.yaw_rad, cov)


class GraphIsam2(_GraphEstimator):
    """Online iSAM2: one update per keyframe, causal output (``final``: smoothed).

    Without a sensor profile it learns one online (``config.learn_online``):
    once the track (the held keyframes before the start included) spans
    :data:`LEARN_FIRST_S`, at the start when it already does, and then each
    time the track's span has doubled, the sensor profile is fitted to the trajectory
    so far solved with its heading loosened as in graph-batch's first solve
    (:func:`~graphpos.graph.calibration.fit_profile`,
    and the range scale by :func:`~graphpos.graph.calibration.estimate_range_scale`
    when graph-batch would estimate it) and applied to the readings still
    to come (:meth:`GraphBuilder.recalibrate`); a camera's bearing term
    (:func:`~graphpos.graph.calibration.fit_range_terms`) corrects the
    recorded readings as well (:meth:`GraphBuilder.correct_range_records`),
    so the next learning fits what is left (MRCLAM6 mean RMS 0.526 to
    0.431 m; robot 1 worse, 0.446 to 0.514 m); so does the compass bias
    (``compass_bias``, solved for in the learning solve and applied when
    significant), correcting the recorded compass readings as well. Until a
    learning has fitted the yaw rate's scale, the inertial graph's IMU factors
    take the turn-rate scale density of an uncalibrated yaw rate
    (``config.uncalibrated_turn_scale_density_per_sqrt_s``). Only data received so far is
    used: the output stays causal. The doubling keeps the learning's cost a
    small multiple of one batch solve of the drive. graph-fixed-lag does not
    learn (it keeps no history); without learning the two give the same
    causal output (:class:`GraphFixedLag`).

    Its causal covariances are checked against its own smoothed estimate
    and widened where the rows turned out further off than they said
    (:meth:`_check_covariance`; ``config.covariance_check``).

    Its iSAM2 keeps a window of ``config.isam2_window_s``
    (:class:`~graphpos.graph.smoothers.WindowedIsam2Smoother`): full iSAM2's
    per-update cost grows with the drive (8.5x from the first to the last
    sixth of an hour). The builder keeps every factor, so learning and
    ``final`` still solve the whole track; a learnt range model rebuilds the
    ranges still in the window.
    """

    name = "graph-isam2"
    checks_covariance = True
    summary = "GTSAM iSAM2 factor graph, one update per 10 Hz keyframe; causal output (final=True: smoothed)"

    @property
    def learns_online(self) -> bool:
        """Without a sensor profile (``config.learn_online``). Its first learning fits the wheel's scale
        :data:`LEARN_FIRST_S` in, so its wheel factors keep the configured density: widened until then, the
        result was mixed (MRCLAM6's mean RMS 0.394 to 0.407 m, realistic seeds 4-19 0.222 to 0.215 m)."""
        return self.config.learn_online and self.profile is None

    def start(self, drive: Drive) -> None:
        super().start(drive)
        self._next_learn_s = LEARN_FIRST_S if self.learns_online else None
        self._learnt_k = 0
        self._learning: list[dict] = []
        self._compass_seen: tuple[float, float] | None = None  # the total compass bias the last learning found, and its sigma
        self._implausible_said = False  # whether a learning left out as implausible has been said

    def _apply(self, increments: list[Increment]) -> list[OutputRow]:
        out = super()._apply(increments)
        start = self.builder.diagnostics.get("anchor_keyframe")
        if out and start is not None:
            k = self.builder.last_keyframe  # every closed keyframe is in the smoother now
            received_s = k * self.builder.period_s  # the held track before the start is data too
            if self._next_learn_s is not None and received_s >= self._next_learn_s:
                self._learn(k)
                while received_s >= self._next_learn_s:
                    self._next_learn_s *= 2.0
        return out

    def _learn(self, k: int) -> None:
        from graphpos.graph.calibration import estimate_range_scale, fit_profile, implausible_calibration
        from graphpos.profile import ImplausibleProfileError

        b = self.builder
        what = f"{self.name} on '{self._drive_name}' (learning at keyframe {k})"
        values = b.history_values(self.smoother.estimate())
        scale = b.range_scale
        reported = b.reports_ranges
        if self._estimates_range_scale() and b.range_records:
            scale, _ = estimate_range_scale(b, values, self.config, what)
        # fitted to a solve whose heading may depart from the turn rate (graph-batch's first solve loosens it the same way)
        c = self.config
        loose2 = (c.turn_scale_density_per_sqrt_s * c.calibration_odometry_factor) ** 2 - c.turn_scale_density_per_sqrt_s**2
        if c.compass_bias == "estimate":  # the compass bias, solved for with the rest (as graph-batch does)
            values = b.estimate_compass_bias(c.compass_bias_sigma_rad, values)
        try:
            graph = b.graph(scale, extra_turn_density2=loose2)
            values = optimise(graph, values, c, what, relative_tol=1e-3)
            found = fit_profile(b, values, c, self._drive_name, since_keyframe=self._learnt_k)
            if found is not None and found.compass_bias_rad:
                found = dataclasses.replace(found, compass_bias_rad=self._confirmed_compass_bias(found.compass_bias_rad, graph, values, what))
        except ImplausibleProfileError as exc:
            # online, one learning that no sensor can have is left out (and said), not the run's end
            found = None
            if not self._implausible_said:  # once a drive
                self._implausible_said = True
                b.diagnostics.setdefault("warnings", []).append(
                    f"{implausible_calibration(exc, self._drive_name)} (at keyframe {k}; that learning was left out)")
        finally:
            b.estimate_compass_bias(None, values)  # the final smoothing's graph has the compass as corrected
        if found is None:
            return
        # a camera's bearing term (with its offset) corrects the readings to come and those recorded; other
        # drives' ranges keep their readings (the offset is the median residual about a track solved with them)
        camera = found.range_bearing2_m_per_rad2 != 0.0 and self.range_model is None
        corrections = b.corrections.combined(dataclasses.replace(
            found, range_scale=1.0, range_offset_m=found.range_offset_m if camera else 0.0,
            range_bearing2_m_per_rad2=found.range_bearing2_m_per_rad2 if camera else 0.0))
        if camera:
            b.correct_range_records(found.range_offset_m, found.range_bearing2_m_per_rad2)
        if found.compass_bias_rad:
            b.correct_compass_records(found.compass_bias_rad)
        range_model = found.range_model() if reported and self.range_model is None else None
        b.recalibrate(corrections, scale, range_model)
        rebuilt = self._rebuild_ranges(values, what) if range_model is not None else 0
        self._learnt_k = k
        self._learning.append({"keyframe": k, "range_scale": scale, "gyro_bias_radps": corrections.gyro_bias_radps,
                               "yaw_rate_scale": corrections.yaw_rate_scale, "wheel_scale": corrections.wheel_scale,
                               "range_offset_m": corrections.range_offset_m, "range_bearing2_m_per_rad2": corrections.range_bearing2_m_per_rad2,
                               "compass_bias_rad": corrections.compass_bias_rad, "ranges_rebuilt": rebuilt})

    def _confirmed_compass_bias(self, found_rad: float, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, what: str) -> float:
        """The learnt compass bias (on the readings as corrected so far) to apply: ``found_rad``, or 0 until confirmed.

        A bias is applied when it is significant (beyond
        :data:`COMPASS_BIAS_SIGNIFICANCE` sigmas of its marginal) and the
        previous learning, on half the data, found the same total bias to
        within as many sigmas of the two's difference: a deviation is constant, while a fault that
        displaces the track for a while (GNSS multipath, a magnetic
        disturbance) puts a bias on one learning's solve that the next,
        longer one does not repeat (urban-rsu-gnss with 21 s of multipath:
        -3.8 degrees at 30 s, -0.4 at 60 s; applied at once, graph-isam2
        never recovered from the multipath). The compass factors already in
        the window keep their readings: swapped for corrected ones (as the
        ranges are), iSAM2 relinearised for seconds after and its CPU rose
        3-4x on paper-profile drives for 0.1-0.2 m.
        """
        sigma = math.sqrt(marginal_covariances(graph, values, [COMPASS_BIAS_KEY], what)[0][2, 2])
        total = self.builder.corrections.compass_bias_rad + found_rad
        previous, self._compass_seen = self._compass_seen, (total, sigma)
        if abs(found_rad) < COMPASS_BIAS_SIGNIFICANCE * sigma or previous is None:
            return 0.0
        return found_rad if abs(total - previous[0]) < COMPASS_BIAS_SIGNIFICANCE * math.hypot(sigma, previous[1]) else 0.0

    def _rebuild_ranges(self, values: gtsam.Values, what: str) -> int:
        """Swap every range factor in iSAM2's window for one with the learnt scale and sigma.

        Left as they were built, the ranges received before a learning keep
        the old scale and pull the causal estimate for as long as they are
        near. The range records hold each reading, so iSAM2 removes the old
        factors and takes the rebuilt ones in the same updates. Ranges of
        marginalised keyframes are part of the window's prior and stay.
        The swap is made :data:`REBUILD_CHUNK_FACTORS` factors per update:
        one iSAM2 update (QR) that swapped them all took time growing much
        faster than their number (a 20 Hz ranging radio's 300 s drive:
        2048 factors 3.1 s, 4564 31 s, 6693 102 s, 80 % of the run; in
        chunks 1.1, 2.7 and 3.3 s, the causal RMS 3.94 -> 3.89 m).
        Returns how many were rebuilt.
        """
        b = self.builder
        b.reweight_ranges(values)
        isam = self.smoother.isam
        factors, theta = isam.getFactorsUnsafe(), isam.getLinearizationPoint()
        kinds = (gtsam.RangeFactor2D, gtsam.RangeFactor3D)
        old = [i for i in range(factors.size()) if factors.exists(i) and isinstance(factors.at(i), kinds)]
        records = [r for r in b.range_records if theta.exists(self.model.pose_key(r.keyframe)) and theta.exists(r.landmark_key)]
        # the window's range factors are those of the records whose keys it holds: all go, all come back rebuilt
        if collections.Counter(tuple(factors.at(i).keys()) for i in old) != collections.Counter((self.model.pose_key(r.keyframe), r.landmark_key) for r in records):
            return 0  # not one record per factor (should not happen): leave the graph as it is
        by_keys: dict[tuple, list[int]] = collections.defaultdict(list)
        for i in old:
            by_keys[tuple(factors.at(i).keys())].append(i)
        for first in range(0, len(records), REBUILD_CHUNK_FACTORS):
            fresh, removed = gtsam.NonlinearFactorGraph(), []
            for r in records[first:first + REBUILD_CHUNK_FACTORS]:
                fresh.add(b.range_factor(r, b.range_scale))
                removed.append(by_keys[(self.model.pose_key(r.keyframe), r.landmark_key)].pop())
            try:
                isam.update(fresh, gtsam.Values(), removed)
            except RuntimeError as exc:
                raise gtsam_error(exc, f"{what}: rebuilding the ranges") from None
        return len(records)

    def _estimate(self, rows: list[OutputRow]) -> Estimate:
        est = super()._estimate(rows)
        if getattr(self, "_learning", None):
            est.diagnostics["online_calibration"] = self._learning
        return est

    def finish(self) -> Estimate:
        self._apply(self.builder.flush())
        if not self.config.final or not self.builder.started:
            return self._estimate(self.rows)
        what = f"{self.name}: final smoothing"
        try:
            self.smoother.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), {}, ANCHOR_ITERATIONS)
            recent = self.smoother.estimate()
        except RuntimeError as exc:
            raise gtsam_error(exc, what) from None
        # the whole drive's factors (iSAM2 holds only its window's), from the
        # smoother's estimate: iSAM2 relinearises only variables that moved
        # past their thresholds, so even within the window a warm
        # Levenberg-Marquardt pass finishes it
        graph = self.builder.graph()
        values = optimise(graph, self.builder.history_values(recent), self.config, what)
        covs = None
        if self.config.output_covariance:
            covs = marginal_covariances(graph, values, [self.model.pose_key(k) for k in range(self.builder.last_keyframe + 1)], what)
        return self._estimate(_rows_from_values(self.model, self.builder, values, covs))


def _rows_from_values(model, builder: GraphBuilder, values: gtsam.Values, marginals: list | None) -> list[OutputRow]:
    source = ValuesSource(values)
    rows = []
    for k in range(builder.last_keyframe + 1):
        state = model.read(source, k, builder.speeds[k])
        cov = model.position_cov(marginals[k], state) if marginals is not None else None
        rows.append(_output_row(builder.keyframe_time(k), state, cov))
    return rows


class GraphFixedLag(_GraphEstimator):
    """Incremental fixed-lag smoother: bounded window, flat cost and memory; causal output.

    Its causal outputs equal graph-isam2's (to about 1e-11 m on simulated
    paper drives, beyond the lag too: the window is marginalised in
    batches, :class:`~graphpos.graph.smoothers.FixedLagSmoother`) when
    graph-isam2 learns no profile online (``learn_online=False``, or a
    sensor profile given); their covariances too until the first
    covariance check widens either's (:meth:`_check_covariance`: graph-isam2
    compares its rows with its smoothed estimate 30 s later, this smoother
    within its window, :meth:`_check_timing_s`). It does not learn one itself: learning solves the
    whole track so far and rebuilds every range factor received
    (:class:`GraphIsam2`), the history a fixed-lag smoother exists not to
    keep. With learning (graph-isam2's default), graph-isam2 departs from
    it once a learnt profile is applied (on paper-straight seeds 0-3, from
    30 s on: 0.12-0.39 m at most, at the drive's end). Learning nothing, it
    takes the yaw rate's scale as unknown throughout unless a sensor
    profile gives it (:attr:`widens_uncalibrated_scales`): on realistic
    300 s drives, where the scale is up to 30 % off, its mean RMS went from
    2.07 to 0.65 m on seeds 0-3 and from 3.36 to 0.72 m on seeds 4-19
    (fresh seeds 20-29: 0.69 m); on the ideal paper drives, whose gyro has
    no scale error, from 0.378 to 0.385 m. So does the wheel's (0.47, 0.57
    and 0.51 m; see ``config.uncalibrated_wheel_scale_density_per_sqrt_s``). The start differs too where ignition needs longer than
    the window: only the last ``fixed_lag_s - max_delay_s`` of the held
    track are released (:class:`~graphpos.graph.builder.GraphBuilder`).
    """

    name = "graph-fixed-lag"
    summary = "GTSAM incremental fixed-lag smoother (default 10 s lag), flat cost for hours-long drives; causal output"
    checks_covariance = True

    def _check_timing_s(self) -> tuple[float, float]:
        """The check within the window: a row is checked 0.75 windows after it, every 0.1 window, so it is
        still in the smoother (which keeps a key one window or a little more). A shorter lag says less (the
        smoothed estimate shares more of the row's error, :data:`COVARIANCE_CHECK_LAG_S`): on MRCLAM6 robots
        1-5, ANEES 21.9, 94.6, 298.4, 38.4, 30.9 unchecked; 21.2, 26.3, 25.9, 20.3, 18.1 checked 5 s after;
        19.4, 20.1, 19.8, 17.0, 14.0 checked 7.5 s after (Plaza1 0.31 throughout)."""
        lag_s, every_s = super()._check_timing_s()
        return min(lag_s, 0.75 * self.config.fixed_lag_s), min(every_s, 0.1 * self.config.fixed_lag_s)

    def _make_smoother(self, model_name: str):
        return FixedLagSmoother(model_name, self.config.fixed_lag_s)

    def _builder_options(self) -> dict[str, Any]:
        return {
            "max_delay_s": self.config.max_delay_s,
            "keep_history": False,
            "release_window_s": self._release_window_s(self.config.fixed_lag_s),
        }


class GraphFixedLagSmoothed(GraphFixedLag):
    """The fixed-lag smoother's own smoothed output: each keyframe just before it leaves the window.

    The same smoother and updates as ``graph-fixed-lag``; a keyframe's row
    is read (state and marginal covariance) right before the update that
    marginalises it, i.e. from the data up to between ``fixed_lag_s`` and
    ``fixed_lag_s`` + :data:`~graphpos.graph.smoothers.MARGINALISE_EVERY_S`
    after it; the keyframes still in the window when the drive ends are read
    from the final window. Rows are output that late (``process`` returns
    them then), and the diagnostics say so (``output``,
    ``output_delay_s``). Keyframes released at the start (the held track's
    last seconds) get rows too.
    """

    name = "graph-fixed-lag-smoothed"
    summary = "GTSAM incremental fixed-lag smoother, smoothed output: each keyframe as it leaves the 10 s window"
    checks_covariance = False  # its rows are the smoothed estimates the check would compare with

    def start(self, drive: Drive) -> None:
        super().start(drive)
        self._pending: list[tuple[int, float]] = []  # keyframes in the window without a row yet, and their mean speeds

    def _apply(self, increments: list[Increment]) -> list[OutputRow]:
        out = []
        for inc in increments:
            if inc.late or inc.released:
                out += self._leaving(self.smoother.cutoff_s(inc.timestamps))
                self._update(inc)
                self._pending += [(k, inc.speeds[k]) for k in inc.released]
        self.rows.extend(out)
        return out

    def _leaving(self, cutoff_s: float) -> list[OutputRow]:
        """Rows of the pending keyframes the next update marginalises (every one for ``cutoff_s`` inf)."""
        n = 0
        while n < len(self._pending) and self.smoother.stamp(self.builder.keyframe_time(self._pending[n][0])) < cutoff_s:
            n += 1
        rows = []
        for k, speed_mps in self._pending[:n]:
            rows.append(self._row(k, self.model.read(self.smoother.source(), k, speed_mps, with_bias=False)))
        del self._pending[:n]
        return rows

    def finish(self) -> Estimate:
        self._apply(self.builder.flush())
        self.rows.extend(self._leaving(math.inf))
        est = self._estimate(self.rows)
        est.diagnostics.update(output="smoothed: each keyframe from the data up to output_delay_s after it (the last ones: to the drive's end)",
                               output_delay_s=[self.config.fixed_lag_s, self.config.fixed_lag_s + MARGINALISE_EVERY_S])
        return est


class GraphBatch(_GraphEstimator):
    """Levenberg–Marquardt over the whole drive, from the causal iSAM2 pass; marginal covariances.

    Offline, a reading counts as arriving when it was taken, and ``run``
    takes the measurements in that order (``merge_by = "t"``): no reading is
    late, whenever it reached the computer (even after the odometry ended).
    """

    name = "graph-batch"
    summary = "GTSAM batch smoother (Levenberg-Marquardt over the whole drive, from an iSAM2 pass) with marginal covariances"
    merge_by = "t"
    scales_rss_ranges = True
    #: Its solves count repeated odometry readings once (MRCLAM6 logs each commanded speed over 6-11 rows of
    #: 100): robots 1-5 RMS 0.305, 0.148, 0.153, 0.254, 0.171 m -> 0.246, 0.144, 0.146, 0.240, 0.162, ANEES
    #: 3.68, 2.18, 2.43, 6.17, 3.41 -> 1.58, 0.95, 1.50, 1.91, 1.68 (Plaza1 and simulated drives repeat none).
    #: Its calibration solve counts rows, see :meth:`run`.
    counts_new_readings = True

    def _builder_options(self) -> dict[str, Any]:
        # the whole held track is released, whatever the window (the seeding smoother marginalises what is
        # older at once): cut to the window, graph-batch on MRCLAM robot 1 ended at 1.13 m RMS instead of 0.36 m;
        # offline, a track ignition never starts is solved on its own (GraphBuilder._start_from_graph)
        return {"max_delay_s": math.inf, "solve_unstarted": True}

    def process(self, measurement: Measurement) -> list[OutputRow]:
        m = measurement if measurement.arrival_s == measurement.t_s else measurement._replace(arrival_s=measurement.t_s)
        return self._apply(self.builder.add(m))

    def run(self, drive: Drive) -> Estimate:
        """One solve with a given profile; else self-calibration (``config.self_calibrate``): two or three.

        The first solve (odometry loosened, range and wheel scales estimated)
        gives the drive's sensor profile; the second solves the corrected
        drive with the profile's noise levels. Ranges that carry a bearing
        (a camera's) also get the profile's bearing term, fitted about the
        first solve's track (:func:`~graphpos.graph.calibration.fit_range_terms`;
        MRCLAM6, mean RMS over the five robots 0.295 to 0.248 m), then
        fitted again about the second solve's track and solved a third
        time (0.225 to 0.215 m, every robot better, ANEES as before). On
        drives that report ranges the final solves, given the drive's profile,
        also search the offset common to every range (``range_offset`` ``auto``,
        :func:`~graphpos.graph.calibration.estimate_range_offset`), which the
        residuals about a solved track cannot show (MRCLAM6: mean RMS 0.215
        to 0.205 m, ANEES 4.0-11.8 to 3.2-6.7; Plaza1 0.240 to 0.241 m). Its
        diagnostics carry the profile (``profile``) and the first solve's
        figures (``calibration_pass``).

        The first solve counts odometry rows even where they repeat a
        reading (:attr:`counts_new_readings` off), as the online graphs do:
        the profile's range noise is fitted about its track, and with the
        wheel looser that track follows the ranges more closely and the
        noise comes out lower (MRCLAM6 robot 1: 0.343 -> 0.257 m), too low
        for another vehicle's drive online (robot 1's profile on robot 4:
        graph-isam2 0.63 m against 0.42 with its own, from a start 35
        degrees off that it kept for 55 s without a landmark in view).
        """
        if self.profile is not None or not self.config.self_calibrate:
            return super().run(drive)
        from graphpos.graph.calibration import implausible_calibration
        from graphpos.profile import ImplausibleProfileError

        try:
            return self._self_calibrated(drive)
        except ImplausibleProfileError as exc:
            raise EstimationError(implausible_calibration(exc, drive.name)) from None

    def _self_calibrated(self, drive: Drive) -> Estimate:
        """:meth:`run`'s self-calibration (two or three solves)."""
        from graphpos.graph.calibration import fit_profile, fit_range_terms, undetermined_noise_warning

        c = self.config
        t0 = time.perf_counter()
        loose = dataclasses.replace(c, self_calibrate=False, output_covariance=False,
                                    heading_drift_sigma_radps=c.heading_drift_sigma_radps * c.calibration_odometry_factor,
                                    turn_scale_density_per_sqrt_s=c.turn_scale_density_per_sqrt_s * c.calibration_odometry_factor)
        first = self._calibration_solve(loose)
        first.counts_new_readings = False
        first_estimate = first.run(drive)
        if not first.builder.started or not first.builder.odometry_records:
            return first_estimate.with_wall_time(time.perf_counter() - t0)
        profile = fit_profile(first.builder, first.values, first.config, drive.name, redundancy=True)
        bearing = profile is not None and profile.range_bearing2_m_per_rad2 != 0.0
        del first  # its graph and values go before the second solve builds its own
        release_freed_memory()
        if profile is None:  # too short a drive, or no motion, to calibrate on: one plain solve
            plain = self._calibration_solve(dataclasses.replace(c, self_calibrate=False))
            est = plain.run(drive)
            self.builder, self.model, self.values, self.config = plain.builder, plain.model, getattr(plain, "values", None), plain.config
            return est.with_wall_time(time.perf_counter() - t0)
        # the readings' delay only with a wheel speed: without one the IMU's velocity absorbs any shift of the
        # readings in time (an IMU-and-UWB drive stamped on time found -0.5 s, the search's bound, and 1 m of error)
        delay = c.range_delay == "estimate" or (c.range_delay == "auto" and drive.has("wheel"))
        final_config = dataclasses.replace(c, self_calibrate=False, range_scale="off", wheel_scale="off",
                                           range_delay="estimate" if delay else "off")
        final = self._calibration_solve(final_config, profile)
        est = final.run(drive)
        profile = _with_found_terms(profile, est)
        refit = fit_range_terms(final.builder, final.values) if bearing else None
        if refit is not None and refit["range_bearing2_m_per_rad2"] != 0.0:
            # the first solve's track had absorbed part of the bearing term (its ranges were uncorrected):
            # fitted again about the corrected solve's track (a correction of the corrected readings), and solved once more
            # (MRCLAM6: RMS lower on all five robots); the sigma stays the larger: residuals about a track solved with
            # these very readings shrink
            profile = dataclasses.replace(
                profile, range_offset_m=profile.range_offset_m + profile.range_scale * refit["range_offset_m"],
                range_bearing2_m_per_rad2=profile.range_bearing2_m_per_rad2 + profile.range_scale * refit["range_bearing2_m_per_rad2"],
                range_sigma0_m=max(profile.range_sigma0_m, refit["range_sigma0_m"]))
            del final
            release_freed_memory()
            final = self._calibration_solve(final_config, profile)
            est = final.run(drive)
            profile = _with_found_terms(profile, est)
        self.builder, self.model, self.values, self.config = final.builder, final.model, getattr(final, "values", None), final.config
        diagnostics = {**est.diagnostics, "profile": profile.to_dict(), "range_scale": profile.range_scale, "wheel_scale": profile.wheel_scale,
                       **({"compass_bias_rad": profile.compass_bias_rad} if "compass_bias_rad" in est.diagnostics else {}),
                       "calibration_pass": {k: first_estimate.diagnostics.get(k) for k in ("range_scale", "wheel_scale", "range_scale_solves")}}
        warning = undetermined_noise_warning(profile)  # the drive too short to settle its heading noise
        if warning:
            diagnostics["warnings"] = [*diagnostics.get("warnings", []), warning]
        return dataclasses.replace(est, diagnostics=diagnostics, wall_time_s=time.perf_counter() - t0)

    def _calibration_solve(self, config: GraphConfig, profile=None) -> GraphBatch:
        """One solve of the self-calibration (:meth:`run`), whose odometry never takes the uncalibrated scale
        densities (:attr:`widens_uncalibrated_scales`): the first solve loosens it to fit the scales; the final
        solves have the scales fitted to this drive's own turns, even where it turned too little to fit them for
        another drive (widened, graph-batch's mean RMS on the paper profile's drives, paper-straight and
        paper-comprehensive seeds 0-5, went from 1.041 to 1.109 m, ideal 0.230 to 0.236 m); a drive too short to
        calibrate on is solved as configured (widened, a 15 s drive started by a user heading 180 degrees off
        stayed 8.3 m off in the inertial graph)."""
        solve = GraphBatch(config, self.layout, self.range_model, self.initial_pose, profile)
        solve.widens_uncalibrated_scales = False
        return solve

    def start(self, drive: Drive) -> None:
        super().start(drive)
        self._pending: Increment | None = None

    def _apply(self, increments: list[Increment]) -> list[OutputRow]:
        """The seeding pass: one iSAM2 update per :data:`BATCH_PASS_CHUNK_S` of keyframes.

        Keyframes inside a chunk start from dead reckoning off the last
        update, which is all the batch solve needs; one update per 50
        keyframes makes the pass several times cheaper than the online one.
        """
        for inc in increments:
            if inc.late:
                self._flush_pending()
                self._update(inc)
                continue
            if not inc.released:
                continue
            if self._pending is None:
                self._pending = inc
            else:
                _merge(self._pending, inc)
            if inc.t_s - self.builder.keyframe_time(self._pending.released[0]) >= BATCH_PASS_CHUNK_S:
                self._flush_pending()
        return []

    def _flush_pending(self) -> None:
        if self._pending is not None:
            self._update(self._pending)
            self._pending = None

    def finish(self) -> Estimate:
        from graphpos.graph.calibration import estimate_range_delay, estimate_range_offset, estimate_range_scale, estimate_wheel_scale

        self._apply(self.builder.flush())
        self._flush_pending()
        if not self.builder.started:
            return self._estimate([])
        try:
            # the smoother's estimate (the marginalised keyframes as they left its window): a start for Levenberg-Marquardt
            initial = self.builder.history_values(self.smoother.estimate())
        except RuntimeError as exc:
            raise gtsam_error(exc, f"{self.name}: initial estimate") from None
        self.smoother = None  # the seeding pass's Bayes tree is done with: its memory goes before the batch solves
        what = f"{self.name} on '{self._drive_name}'"
        if self.config.compass_bias == "estimate":
            initial = self.builder.estimate_compass_bias(self.config.compass_bias_sigma_rad, initial)
        fit_wheel = self.config.wheel_scale == "estimate" and self.builder.odometry_records and self.builder.odometry.has_speed
        if self._estimates_range_scale() and self.builder.range_records:
            # the range scale first: the causal pass's ranges (unscaled) would
            # pass their scale error on to the wheel's
            scale, initial = estimate_range_scale(self.builder, initial, self.config, what)
            self.builder.range_scale = scale
        # tag ranges' sigmas at the distances of the causal (or scale) solve, not the readings'
        self.builder.reweight_ranges(initial)
        if self.config.range_delay == "estimate" and self.builder.has_tag_ranges and self.builder.range_records:
            # after the scale (whose error would otherwise pass into the delay) and the sigmas: where no delay is
            # kept, the search's undelayed solve is the final graph's, and the final solve starts from it converged
            delay_s, initial = estimate_range_delay(self.builder, initial, self.config, what)
            if delay_s:
                self.builder.range_records = self.builder.delayed_range_records(delay_s)
                self.builder.range_delay_s = delay_s
                self.builder.diagnostics["range_delay_s"] = delay_s
                self.builder.reweight_ranges(initial)
        if fit_wheel:
            self.builder.wheel_drift_density = self.config.wheel_scale_density_per_sqrt_s * self.config.batch_wheel_drift_factor
            # a solve whose wheel factors allow for a scale error (their drift term) follows the ranges, not the
            # wheel: the scale fitted to it is where the search for the scale starts (estimate_wheel_scale), whose
            # factors then keep only their white noise. A 0.1 % tolerance fits it as well as 0.01 % (12 seeds:
            # RMS 0.372 / 0.309 m against 0.370 / 0.306) in 4 iterations instead of 6 on a 10-minute drive
            initial = optimise(self.builder.graph(), initial, self.config, what, relative_tol=1e-3)
            self.builder.reweight_ranges(initial)
        offset = None
        search_offset = self.config.range_offset == "estimate" or (self.config.range_offset == "auto" and self.profile is not None)
        if search_offset and self.builder.range_records and self.builder.reports_ranges:
            # before the wheel scale: ranges to the landmarks ahead that read long are matched by a track moved
            # forward, and a wheel scale searched with them uncorrected took up part of the offset (a 0.3 m offset was
            # found as 0.23 m, ANEES 3.7); the drift-tolerant wheel leaves the offset to the turns
            offset = estimate_range_offset(self.builder, initial, self.config, what)
            self.builder.range_offset_m = offset.offset_m
            self.builder.diagnostics.update(range_offset_m=offset.offset_m, range_offset_sigma_m=offset.sigma_m)
            initial = offset.values
        if fit_wheel:
            _, initial = estimate_wheel_scale(self.builder, initial, self.config, what)
        graph = self.builder.graph()
        # each search returns the solution at what it found, with everything before it kept
        values = initial if (offset is not None or fit_wheel) else optimise(graph, initial, self.config, what)
        self.values = values
        covs = None
        compass = self.builder.compass_bias_sigma_rad is not None and values.exists(COMPASS_BIAS_KEY)
        if self.config.output_covariance:
            keys = [self.model.pose_key(k) for k in range(self.builder.last_keyframe + 1)]
            covs = marginal_covariances(graph, values, keys + [COMPASS_BIAS_KEY] if compass else keys, what)
        if compass:
            self.builder.diagnostics["compass_bias_rad"] = self.model.compass_bias(values)
            if covs is not None:
                self.builder.diagnostics["compass_bias_sigma_rad"] = float(math.sqrt(covs.pop()[2, 2]))  # yaw: Pose2 and Pose3 tangent index 2
        rows = _rows_from_values(self.model, self.builder, values, covs)
        if covs is not None and offset is not None and offset.sigma_m is not None:
            # the offset is estimated, not known: its variance reaches each position through the solve's sensitivity
            # (consider covariance); with the searched offset, MRCLAM6's ANEES went from 4.0-11.8 to 3.2-6.7
            j = offset.position_per_m
            rows = [dataclasses.replace(row, cov_en_m2=row.cov_en_m2 + offset.sigma_m**2 * np.outer(j[k], j[k])) for k, row in enumerate(rows)]
        return self._estimate(rows)


#: graph-isam2 applies a learnt compass bias beyond this many of its sigmas, found again by the next learning to as many.
COMPASS_BIAS_SIGNIFICANCE = 2.0

#: graph-isam2 swaps a learning's rebuilt range factors into iSAM2 this many per update (:meth:`GraphIsam2._rebuild_ranges`).
REBUILD_CHUNK_FACTORS = 1000

#: graph-isam2's first online calibration: once its track (held keyframes included) spans this many s (then 2x, 4x ...).
LEARN_FIRST_S = 15.0
#: graph-isam2 compares a causal row with its smoothed estimate of the same keyframe once this much later data
#: has come, s (:meth:`GraphIsam2._check_covariance`).
COVARIANCE_CHECK_LAG_S = 30.0
#: How often graph-isam2 checks, s, and over how long a span of rows its factor is a mean, s. Lag and span
#: chosen on MRCLAM6 robots 1-2 (lags 10-90 s, spans 60-300 s: the smoothed estimate shares less of a row's
#: error the more later data it has; 30 s / 300 s best), checked on robots 3-5 and Plaza1. Rechecked with the
#: check's present statistic (:func:`difference_nees`) on robots 1-5: lags 5, 10, 45 and 60 s all worse than 30 s
#: (mean ANEES 8.7, 7.3, 6.8, 8.5 against 6.2).
COVARIANCE_CHECK_EVERY_S = 10.0
COVARIANCE_CHECK_WINDOW_S = 300.0
#: Fewest checked rows (10 s of them, :data:`COVARIANCE_CHECK_SPACING_S`) that set the factor.
COVARIANCE_CHECK_MIN_ROWS = 10
#: One causal row is checked per this many s: a row's error persists for seconds, and each check costs a
#: marginal of the smoother, dearer the older its key (MRCLAM6 ANEES the same to 0.1 checking every row, one
#: per 0.5 s or one per s; CPU with the check / without, Plaza1 and MRCLAM6 robots 1 and 3: graph-isam2 1.02,
#: graph-fixed-lag 1.17).
COVARIANCE_CHECK_SPACING_S = 1.0
#: Until rows checked :data:`COVARIANCE_CHECK_LAG_S` after them set the factor (40 s after a start), rows checked
#: this much after them do, s (the lag graph-fixed-lag checks at in its default window). A short lag says less,
#: but a start's first rows, when learning has seen least, were the most overconfident: graph-isam2 on MRCLAM6
#: robots 1-5 ANEES 10.5, 2.2, 8.9, 6.0, 3.2 -> 9.1, 2.1, 6.9, 6.0, 3.0 (Plaza1 1.05 -> 1.03); on 150 s pieces
#: (``benchmarks/real_drives.py --segments 150``) median ANEES 32 -> 17.
COVARIANCE_CHECK_EARLY_LAG_S = 7.5
#: Least share of a row's variance, in any direction, that the check's difference is taken to carry
#: (:func:`difference_nees`): where later data improved a direction by less, the difference says little about it.
COVARIANCE_CHECK_MIN_SHARE = 0.1


def difference_nees(d_en_m: np.ndarray, causal_en_m2: np.ndarray, smoothed_en_m2: np.ndarray) -> float:
    """``d' (P - S)^-1 d`` of a causal row's difference ``d`` from the smoothed estimate (2 on average when consistent).

    ``P - S`` is taken in the frame where ``P`` is the identity (``P = L L'``,
    ``W = L^-1 (P - S) L^-T``), where its eigenvalues are the shares of the
    row's variance the smoothing removed (in [0, 1] for a smoother that used
    more data); each is floored at :data:`COVARIANCE_CHECK_MIN_SHARE` and
    capped at 1. NaN when ``P`` is not positive definite.
    """
    try:
        chol = np.linalg.cholesky(causal_en_m2)
    except np.linalg.LinAlgError:
        return math.nan
    inv = np.linalg.inv(chol)
    w = inv @ (causal_en_m2 - smoothed_en_m2) @ inv.T
    share, axes = np.linalg.eigh(0.5 * (w + w.T))
    z = axes.T @ (inv @ d_en_m)
    return float(np.sum(z**2 / np.clip(share, COVARIANCE_CHECK_MIN_SHARE, 1.0)))

#: Span of keyframes per iSAM2 update in graph-batch's seeding pass, s.
BATCH_PASS_CHUNK_S = 5.0


def _with_found_terms(profile, estimate: Estimate):
    """``profile`` with what a final solve found on its corrected readings added: the range offset (found in the
    corrected readings' metres, the profile's in reading units), the compass bias and the tag readings' delay."""
    offset = estimate.diagnostics.get("range_offset_m") or 0.0
    compass = estimate.diagnostics.get("compass_bias_rad") or 0.0
    delay = estimate.diagnostics.get("range_delay_s") or 0.0
    if not offset and not compass and not delay:
        return profile
    return dataclasses.replace(profile, range_offset_m=profile.range_offset_m + offset * profile.range_scale,
                               compass_bias_rad=profile.compass_bias_rad + compass, range_delay_s=profile.range_delay_s + delay)


def _merge(into: Increment, inc: Increment) -> None:
    """Append one increment to another (same smoother update)."""
    into.factors.push_back(inc.factors)
    into.values.insert(inc.values)
    into.timestamps.update(inc.timestamps)
    into.released.extend(inc.released)
    into.speeds.update(inc.speeds)
    into.keyframe, into.t_s = inc.keyframe, inc.t_s
    into.anchoring = into.anchoring or inc.anchoring


def optimise(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, config: GraphConfig, what: str, relative_tol: float = 1e-4) -> gtsam.Values:
    """Levenberg–Marquardt; failures become EstimationError.

    Stops when an iteration lowers the error by less than ``relative_tol``
    (default 0.01 %): from the causal pass, a 10-minute drive's solve reached
    the same error (to 0.1 in 1572) in 5 iterations as in the 9 a 1e-6
    tolerance took.
    """
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.batch_max_iterations)
    params.setRelativeErrorTol(relative_tol)
    params.setAbsoluteErrorTol(1e-6)
    try:
        # a copy: the Values optimize() returns is the optimizer's own and keeps it (its linearised system) alive;
        # the range-scale search holds two solutions, and an hour-long drive's optimizer is ~125 MB
        result = gtsam.Values(gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize())
    except RuntimeError as exc:
        raise gtsam_error(exc, what) from None
    if not np.isfinite(graph.error(result)):
        raise EstimationError(f"{what}: Levenberg-Marquardt diverged (non-finite error)")
    return result


def release_freed_memory() -> None:
    """Return the C heap's freed memory to the system (glibc's ``malloc_trim``; elsewhere nothing).

    graph-batch frees its calibration pass (a whole drive's graph, Bayes
    tree and solves) before the second pass builds its own. glibc keeps
    the freed memory, fragmented, and the second pass's peak comes on top
    of it: on an hour-long drive 1087 MB resident against 9xx MB trimmed.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        ctypes.CDLL(name).malloc_trim(0)
    except (OSError, AttributeError, TypeError):  # not glibc: the allocator keeps what it keeps
        pass


#: marginal_covariances lets go of the Bayes tree's cached shortcuts after this many keys.
MARGINAL_CACHE_KEYS = 500


def marginal_covariances(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int], what: str) -> list[np.ndarray]:
    """Marginal covariance of each key (one factorisation, then per-key solves).

    Each marginal caches its cliques' separator marginals (shortcuts) in
    the Bayes tree, and asked for every keyframe the cache outgrows the
    factorisation (10-minute drive: +40 MB on its 48 MB). Dropped every
    :data:`MARGINAL_CACHE_KEYS` keys, it stays small for 1.5x the time of
    this step (0.66 to 1.0 s on that drive), which keeps graph-batch under
    1 GB on an hour-long drive.
    """
    try:
        marginals = gtsam.Marginals(graph, values)
        out = []
        for i, key in enumerate(keys, 1):
            out.append(marginals.marginalCovariance(key))
            if i % MARGINAL_CACHE_KEYS == 0:
                marginals.deleteCachedShortcuts()
        return out
    except RuntimeError as exc:
        raise gtsam_error(exc, f"{what}: marginal covariances") from None
