"""The estimators of song2016 (J. Navigation) and song2016b (Engineering Letters).

=================  ======================================================  ==========
name               what                                                    output
=================  ======================================================  ==========
``dr``             in-vehicle sensors only: eq. 16 model, wheel + compass  10 Hz
``multilateration`` eq. 38 (misprint corrected), linearised least squares  per scan
``rfid-ekf``       eq. 10-15: position random walk, range updates          per scan
``fusion-ekf``     eq. 16-17: 5-state EKF, ranges + wheel + compass        10 Hz
``fukf``           §5: two local UKFs, federated fusion eq. 34-37          10 Hz
``two-level-ekf``  song2016b: RFID-EKF fixes -> 5-state EKF (eq. 16-17)    10 Hz
=================  ======================================================  ==========

Fallbacks for optional channels (documented here once):

* no accelerometers (an IMU with a yaw gyro only, the Plaza data): eq. 16
  cannot be driven, so the prediction is
  :func:`filters.models.vehicle.rotating_velocity_motion` (velocity turned by
  the measured yaw rate) with ``no_accel_psd_m2ps3`` of process noise; the
  wheel speed then carries the speed;
* no compass: no yaw update (yaw from the gyro integration and, through the
  velocity, from the wheel speed and ranges).

The papers give no noise values for the filters beyond the IMU's (§6: 0.1
m/s^2, 0.2 deg/s); every other default below is ours, chosen on simulated
drives of the papers' specification and stated in the config docstrings.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar
from dataclasses import dataclass, field

import numpy as np

from filters.base import FilterEstimator
from filters.core import ekf
from filters.core.federated import fuse, share_information
from filters.core.ukf import MerweScaledSigmaPoints, UnscentedKalmanFilter
from filters.models import measurements as meas
from filters.models import vehicle
from filters.models.angles import angle_residual, wrap_angle
from filters.models.vehicle import PE, PN, VE, VN, YAW
from graphpos.drive import Drive
from graphpos.errors import ConfigError
from graphpos.estimate import OutputRow
from graphpos.estimator import require_valid_numbers
from graphpos.ignition import StartState

_DEG = math.pi / 180.0


# ---------------------------------------------------------------------------
# Configs
# ---------------------------------------------------------------------------


@dataclass
class VehicleFilterConfig:
    """Tunables of the 5-state filters (fusion-ekf, dr, two-level-ekf, fukf).

    Attributes
    ----------
    output_rate_hz : float
        Output grid (song2016: 10 Hz).
    accel_sigma_mps2, yaw_rate_sigma_radps : float
        1-sigma of one IMU sample (song2016 §6: 0.1 m/s^2, 0.2 deg/s).
    imu_rate_hz : float
        IMU sample rate (§6: 100 Hz); with the sample sigma it gives the
        white-noise density of the process noise, ``sigma^2 / rate``.
    accel_model_psd_m2ps3 : float
        Extra acceleration noise density for what eq. 16 leaves out
        (accelerometer bias, road grade, body roll). Ours.
    yaw_model_psd_rad2ps : float
        Extra yaw noise density for what the gyro's white noise leaves out
        (its bias: the 5-state model has no bias state). Ours.
    no_accel_psd_m2ps3 : float
        Acceleration noise density of the no-accelerometer fallback. Ours.
    wheel_sigma_mps, compass_sigma_rad : float
        Measurement 1-sigmas (the paper gives none; ours). The wheel sigma
        is per 100 Hz sample and inflated well above the encoder noise: it
        also stands for the wheel's scale error, which a white-noise model
        would otherwise average away at 100 Hz (NEES-tuned).
    lateral_velocity_sigma_mps : float or None
        With each wheel speed, a pseudo-measurement of zero sideways body
        velocity with this 1-sigma (the non-holonomic constraint of a wheel
        that does not slip). Not in song2016 (eq. 17 observes the forward
        speed only, leaving the sideways velocity to the integration of a
        biased lateral accelerometer, which drifts metres within seconds
        between the optimised layout's tag groups); None turns it off for
        the paper's literal observation.
    range_gate_probability : float
        Chi-square gate on each range innovation (one degree of freedom);
        1.0 turns gating off (the papers have none).
    range_sigma_scale : float
        Factor on the range model's 1-sigma: a tag's range errors repeat
        from one scan to the next (shadowing, multipath at a place), which
        independent-noise updates over-count. Ours, NEES-tuned.
    """

    output_rate_hz: float = 10.0
    accel_sigma_mps2: float = 0.1
    yaw_rate_sigma_radps: float = 0.2 * _DEG
    imu_rate_hz: float = 100.0
    accel_model_psd_m2ps3: float = 0.003
    yaw_model_psd_rad2ps: float = 1e-5
    no_accel_psd_m2ps3: float = 0.5
    wheel_sigma_mps: float = 1.5
    compass_sigma_rad: float = 2.0 * _DEG
    lateral_velocity_sigma_mps: float | None = 1.0
    range_gate_probability: float = 0.999
    range_sigma_scale: float = 1.2

    #: Float fields exempt from the positivity check (none here).
    _signed_fields: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        require_valid_numbers(self, skip=self._signed_fields)
        require_probability(self.range_gate_probability)


def require_probability(p: float) -> None:
    """The range gate's probability must lie in (0, 1] (1: no gate)."""
    if not 0.0 < p <= 1.0:
        raise ConfigError(f"range_gate_probability must lie in (0, 1], got {p}")


@dataclass
class RfidEkfConfig:
    """Tunables of the RFID-EKF (song2016 eq. 10-15).

    Attributes
    ----------
    speed_sigma_mps : float
        Random-walk process noise: the position may move by this speed times
        the step (1-sigma per axis). Q_RFID is not given in the paper; ours,
        about the test speed.
    init_position_sigma_m : float
        1-sigma of the start position when the filter is the first level of
        ``two-level-ekf`` (started at the start state's position; ours). The
        ``rfid-ekf`` itself takes the user's start pose and its sigma, or
        its first scan.
    range_gate_probability : float
        As in :class:`VehicleFilterConfig`.
    update_iterations : int
        Measurement-update iterations (:func:`filters.core.ekf.iterated_update`);
        1 is eq. 13-15 as printed.
    """

    speed_sigma_mps: float = 2.0
    init_position_sigma_m: float = 0.5
    range_gate_probability: float = 0.999
    update_iterations: int = 3

    def __post_init__(self) -> None:
        require_valid_numbers(self)
        require_probability(self.range_gate_probability)
        if self.update_iterations < 1:
            raise ConfigError(f"update_iterations must be at least 1, got {self.update_iterations}")


@dataclass
class MultilaterationConfig:
    """Tunables of multilateration (song2016 eq. 38).

    Attributes
    ----------
    min_tags : int
        Tags needed for a fix (eq. 38 needs three).
    """

    min_tags: int = 3

    def __post_init__(self) -> None:
        if self.min_tags < 3:
            raise ConfigError(f"a 2-D fix from ranges needs min_tags >= 3, got {self.min_tags}")


@dataclass
class FukfConfig(VehicleFilterConfig):
    """Tunables of the federated UKF (song2016 §5).

    Attributes
    ----------
    beta_few_tags, beta_many_tags : (float, float)
        Information-sharing coefficients (beta_1 ranges, beta_2 wheel/compass)
        when fewer than ``many_tags`` tags are measured, and otherwise
        (§5.4: 0.05/0.95 and 0.8/0.2; beta_m = 0).
    many_tags : int
        §5.4: four.
    ukf_alpha, ukf_beta, ukf_kappa : float
        Scaled unscented transform parameters (the paper prints none; alpha
        0.3 keeps the sigma points near the mean, beta 2 is optimal
        for Gaussians).
    """

    beta_few_tags: tuple[float, float] = (0.05, 0.95)
    beta_many_tags: tuple[float, float] = (0.8, 0.2)
    many_tags: int = 4
    ukf_alpha: float = 0.3
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0

    #: The unscented transform's beta and kappa may be zero or negative.
    _signed_fields: ClassVar[tuple[str, ...]] = ("ukf_beta", "ukf_kappa")

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("beta_few_tags", "beta_many_tags"):
            betas = getattr(self, name)
            if len(betas) != 2 or any(not 0.0 < b < 1.0 for b in betas) or not math.isclose(sum(betas), 1.0):
                raise ConfigError(f"{name} needs two coefficients in (0, 1) that sum to 1 (song2016 eq. 35), got {betas}")
        if self.many_tags < 1:
            raise ConfigError(f"many_tags must be at least 1, got {self.many_tags}")


@dataclass
class TwoLevelEkfConfig(VehicleFilterConfig):
    """Tunables of the two-level EKF (song2016b).

    Attributes
    ----------
    level1 : RfidEkfConfig
        The first-level RFID-EKF. It alone uses the ranges, so the range
        settings inherited at the top level (``range_gate_probability``,
        ``range_sigma_scale``) do not apply; level 1's do.
    fix_covariance_scale : float
        The level-2 EKF takes each level-1 position with the level-1
        covariance times this factor as R (song2016b gives no R). Well above
        1 because consecutive level-1 positions share their errors (the
        level is itself a filter, and lags the motion its random walk does
        not model); 10 makes the level-2 NEES consistent on the simulated
        paper drives (ours).
    """

    level1: RfidEkfConfig = field(default_factory=RfidEkfConfig)
    fix_covariance_scale: float = 10.0


# ---------------------------------------------------------------------------
# Shared 5-state machinery
# ---------------------------------------------------------------------------


def _process_noise(cfg: VehicleFilterConfig, dt: float, accel_psd: float) -> np.ndarray:
    """Discrete white-noise-acceleration Q of the 5-state model over ``dt``.

    Per axis ``q [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` with ``q`` the
    acceleration density (isotropic, so independent of yaw); yaw
    ``q_w dt``.
    """
    q_w = cfg.yaw_rate_sigma_radps**2 / cfg.imu_rate_hz + cfg.yaw_model_psd_rad2ps
    Q = np.zeros((5, 5))
    Q[0, 0] = Q[1, 1] = accel_psd * dt**3 / 3.0
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = accel_psd * dt**2 / 2.0
    Q[2, 2] = Q[3, 3] = accel_psd * dt
    Q[4, 4] = q_w * dt
    return Q


def _accel_psd(cfg: VehicleFilterConfig, has_accel: bool) -> float:
    """Acceleration noise density of the model driven with or without accelerometers."""
    if has_accel:
        return cfg.accel_sigma_mps2**2 / cfg.imu_rate_hz + cfg.accel_model_psd_m2ps3
    return cfg.no_accel_psd_m2ps3


class _InputHold:
    """The IMU input held between samples (zero-order hold) and the model it drives.

    ``u`` is the tuple ``(a_x, a_y, w_z)`` of floats (zeros for the
    accelerations of a sample without them).
    """

    def __init__(self, cfg: VehicleFilterConfig):
        self.cfg = cfg
        self.u = (0.0, 0.0, 0.0)
        self.has_accel = True
        self._q_cache: dict[tuple[float, bool], np.ndarray] = {}
        self._q_last_dt, self._q_last_accel, self._q_last = math.nan, True, None

    def set(self, accel_x: float, accel_y: float, yaw_rate: float) -> None:
        self.has_accel = accel_x == accel_x and accel_y == accel_y  # not NaN
        self.u = (accel_x, accel_y, yaw_rate) if self.has_accel else (0.0, 0.0, yaw_rate)

    def psd(self) -> float:
        return _accel_psd(self.cfg, self.has_accel)

    def Q(self, dt: float) -> np.ndarray:
        if dt == self._q_last_dt and self.has_accel == self._q_last_accel:
            return self._q_last  # the IMU's steady step: the same key as the last call
        self._q_last = Q = self._cached_Q(dt)
        self._q_last_dt, self._q_last_accel = dt, self.has_accel
        return Q

    def _cached_Q(self, dt: float) -> np.ndarray:
        key = (round(dt, 12), self.has_accel)
        Q = self._q_cache.get(key)
        if Q is None:
            Q = _process_noise(self.cfg, dt, self.psd())
            if len(self._q_cache) < 256:
                self._q_cache[key] = Q
        return Q


def _propagate(x: np.ndarray, dt: float, u: np.ndarray, has_accel: bool, jacobian: bool):
    """``(x_next, F)``: eq. 16, or the fallback without accelerometers."""
    if has_accel:
        out, jac = vehicle.improved_motion(x, u, dt, jacobian, input_jacobian=False)
        return out, (jac[0] if jac is not None else None)
    return vehicle.rotating_velocity_motion(x, float(u[2]), dt, jacobian)


def _propagate_steps(x: np.ndarray, dt_s: np.ndarray, u: np.ndarray, has_accel: np.ndarray) -> np.ndarray:
    """States after each of ``K`` held-input steps of :func:`_propagate`, for a stack of states.

    The same recursion as applying :func:`_propagate` step by step (eq. 16,
    or the no-accelerometer fallback), written with cumulative sums over
    the steps so that a whole interval costs a few array operations: the
    yaw after ``j`` steps is ``psi_0 + sum_{i<j} w_i T_i`` whatever the
    state; with accelerometers, ``v_j = v_0 + sum_{i<j} a_i T_i`` and
    ``p_j = p_0 + sum_{i<j} (v_i T_i + a_i T_i^2 / 2)`` with
    ``a_i = R(psi_i) [a_x, a_y]_i``; without, ``v_j = R(sum_{i<j} w_i T_i) v_0``
    and ``p_j = p_0 + sum_{i<j} v_i T_i``. An interval mixing both kinds of
    step (NaN accelerometer samples) is stepped one by one.

    Parameters
    ----------
    x : (k, 5) states
    dt_s : (K,) step lengths
    u : (K, 3) held inputs ``[a_x, a_y, w_z]``
    has_accel : (K,) bool

    Returns
    -------
    (k, K + 1, 5)
        ``[:, j]`` is the state after ``j`` steps (yaw not wrapped).
    """
    k, K = x.shape[0], dt_s.size
    # filled as (state, entry, step), so that the sums over the steps run along contiguous memory
    out = np.empty((k, 5, K + 1))
    traj = out.transpose(0, 2, 1)
    out[:, :, 0] = x
    if K == 0:
        return traj
    all_accel = bool(has_accel.all())
    if not all_accel and has_accel.any():
        for j in range(K):
            traj[:, j + 1] = _propagate(traj[:, j], float(dt_s[j]), u[j], bool(has_accel[j]), False)[0]
        return traj
    theta = np.zeros(K + 1)
    np.cumsum(u[:, 2] * dt_s, out=theta[1:])
    out[:, YAW] = x[:, YAW, None] + theta
    pos, vel, step = out[:, PE : PN + 1], out[:, VE : VN + 1], dt_s
    if all_accel:
        yaw = out[:, YAW, :-1]
        c, s = np.cos(yaw), np.sin(yaw)
        a_en = np.empty((k, 2, K))  # body accelerations turned to east-north
        a_en[:, 0] = u[:, 0] * c - u[:, 1] * s
        a_en[:, 1] = u[:, 0] * s + u[:, 1] * c
        np.cumsum(a_en * step, axis=2, out=vel[:, :, 1:])
        vel[:, :, 1:] += x[:, VE : VN + 1, None]
        dp = vel[:, :, :-1] * step + (0.5 * step * step) * a_en
    else:
        c, s = np.cos(theta), np.sin(theta)
        ve0, vn0 = x[:, VE, None], x[:, VN, None]
        vel[:, 0] = c * ve0 - s * vn0
        vel[:, 1] = s * ve0 + c * vn0
        dp = vel[:, :, :-1] * step
    np.cumsum(dp, axis=2, out=pos[:, :, 1:])
    pos[:, :, 1:] += x[:, PE : PN + 1, None]
    return traj


def _wheel_variances(cfg: VehicleFilterConfig) -> np.ndarray:
    """Diagonal R of a wheel reading: its speed, and the zero-sideways pseudo-measurement if on."""
    if cfg.lateral_velocity_sigma_mps is None:
        return np.array([cfg.wheel_sigma_mps**2])
    return np.array([cfg.wheel_sigma_mps**2, cfg.lateral_velocity_sigma_mps**2])


def _initial_state(start: StartState) -> tuple[np.ndarray, np.ndarray]:
    """The 5-state ``[p_e, p_n, v_e, v_n, psi]`` and its covariance from ignition's start state."""
    x = np.array([start.east_m, start.north_m, start.v_east_mps, start.v_north_mps, wrap_angle(start.yaw_rad)])
    sp, sv, sy = start.position_sigma_m, start.speed_sigma_mps, start.yaw_sigma_rad
    return x, np.diag([sp * sp, sp * sp, sv * sv, sv * sv, sy * sy])


def _gated_range_rows(x, P, tags, ranges, sigmas, probability):
    """Predicted ranges, Jacobian and the rows passing the chi-square gate."""
    r_pred, H = meas.tag_range(x, tags)
    S = np.einsum("ij,jk,ik->i", H, P, H) + sigmas * sigmas
    return r_pred, H, ekf.gate_scalar_rows(ranges - r_pred, S, probability)


class _VehicleEkf(FilterEstimator):
    """The 5-state EKF of song2016 eq. 16-17 (state ``[p_e, p_n, v_e, v_n, psi]``)."""

    config: VehicleFilterConfig

    @classmethod
    def default_config(cls) -> VehicleFilterConfig:
        return VehicleFilterConfig()

    def _init_filter(self, drive: Drive, start: StartState) -> None:
        self._x, self._P = _initial_state(start)
        self._hold = _InputHold(self.config)
        self._R_wheel = _wheel_variances(self.config)
        self._R_compass = np.array([self.config.compass_sigma_rad**2])

    def _predict_to(self, t_s: float) -> None:
        dt = t_s - self._t
        if dt <= 0.0:
            return
        hold = self._hold
        x, F = _propagate(self._x, dt, hold.u, hold.has_accel, True)
        x[4] = wrap_angle(float(x[4]))
        self._x, self._P = ekf.predict(x, F, self._P, self._hold.Q(dt))

    def _on_imu(self, t_s, accel_x, accel_y, yaw_rate):
        self._hold.set(accel_x, accel_y, yaw_rate)

    def _on_wheel(self, t_s, speed_mps):
        if self._R_wheel.size == 1:
            v, H = meas.wheel_speed(self._x)
            z, v = np.array([speed_mps]), np.array([v])
        else:
            v, H = meas.body_velocity(self._x)
            z = np.array([speed_mps, 0.0])
        self._x, self._P, _ = ekf.update(self._x, self._P, z, v, H, self._R_wheel)

    def _on_compass(self, t_s, yaw_rad):
        yaw, H = meas.compass_yaw(self._x)
        res = ekf.update(self._x, self._P, np.array([yaw_rad]), np.array([yaw]), H, self._R_compass, residual=angle_residual)
        res.x[4] = wrap_angle(float(res.x[4]))
        self._x, self._P = res.x, res.P

    def _range_update(self, tags, ranges, sigmas) -> int:
        r_pred, H, ok = _gated_range_rows(self._x, self._P, tags, ranges, sigmas, self.config.range_gate_probability)
        self.diagnostics["ranges_gated"] += int((~ok).sum())
        if ok.any():
            res = ekf.update(self._x, self._P, ranges[ok], r_pred[ok], H[ok], sigmas[ok] ** 2)
            res.x[4] = wrap_angle(float(res.x[4]))
            self._x, self._P = res.x, res.P
            self.diagnostics["ranges_used"] += int(ok.sum())
        return int(ok.sum())

    def _output(self, t_s: float) -> OutputRow:
        x = self._x
        return OutputRow(t_s, float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4]), self._P[:2, :2].copy())


# ---------------------------------------------------------------------------
# The estimators
# ---------------------------------------------------------------------------


class FusionEkf(_VehicleEkf):
    """song2016 Fusion-EKF (eq. 16-17): ranges, wheel speed and compass in one EKF.

    The range rows of a scan are applied together (eq. 13-15) after the
    chi-square gate drops inconsistent ones.
    """

    name = "fusion-ekf"
    summary = "song2016 Fusion-EKF: 5-state EKF on ranges + wheel speed + compass, 10 Hz"
    required_channels = ("imu", "wheel", "rfid")
    optional_channels = ("compass",)

    def _on_scan(self, t_s, tags, ranges, sigmas):
        self._range_update(tags, ranges, sigmas * self.config.range_sigma_scale)


class DeadReckoning(_VehicleEkf):
    """Dead reckoning (song2016 §6.3.2 DR): the eq. 16 model driven by the IMU,
    corrected by the wheel speed and compass only — no position observation,
    so the error grows without bound."""

    name = "dr"
    summary = "dead reckoning: eq. 16 model with wheel speed + compass, no RFID, 10 Hz"
    required_channels = ("imu", "wheel")
    optional_channels = ("compass",)

    #: Start heading 1-sigma ignition must reach: without a compass nothing
    #: corrects the heading afterwards, and 10 degrees (the other filters'
    #: limit) is 17 m of cross-track error per 100 m driven.
    START_YAW_SIGMA_RAD = math.radians(1.0)

    def _ignition_config(self):
        return dataclasses.replace(super()._ignition_config(), max_yaw_sigma_rad=self.START_YAW_SIGMA_RAD)


class TwoLevelEkf(_VehicleEkf):
    """song2016b: level 1 is the RFID-EKF; its positions (1 Hz) are position
    fixes for the level-2 5-state EKF together with wheel speed and compass
    (song2016b eq. 16-17), output at 10 Hz."""

    name = "two-level-ekf"
    summary = "song2016b two-level EKF: RFID-EKF positions + wheel + compass in a 5-state EKF, 10 Hz"
    required_channels = ("imu", "wheel", "rfid")
    optional_channels = ("compass",)
    config: TwoLevelEkfConfig

    @classmethod
    def default_config(cls) -> TwoLevelEkfConfig:
        return TwoLevelEkfConfig()

    def _init_filter(self, drive, start):
        super()._init_filter(drive, start)
        self._level1 = _RfidEkfState(self.config.level1, self._x[:2], start.t_s, self.config.level1.init_position_sigma_m)

    def _on_scan(self, t_s, tags, ranges, sigmas):
        used, gated = self._level1.scan(t_s, tags, ranges, sigmas)
        self.diagnostics["ranges_gated"] += gated
        self.diagnostics["ranges_used"] += used
        if not used:
            return
        z_pred, H = meas.position_fix(self._x)
        R = self._level1.P * self.config.fix_covariance_scale
        res = ekf.update(self._x, self._P, self._level1.x, z_pred, H, R)
        res.x[4] = wrap_angle(float(res.x[4]))
        self._x, self._P = res.x, res.P


class _RfidEkfState:
    """The RFID-EKF filter itself (song2016 eq. 10-15), shared by ``rfid-ekf``
    and the first level of ``two-level-ekf``."""

    def __init__(self, cfg: RfidEkfConfig, x0: np.ndarray, t0_s: float, sigma0_m: float):
        self.cfg = cfg
        self.x = np.array(x0[:2], dtype=np.float64)
        self.P = np.eye(2) * sigma0_m**2
        self.t = t0_s

    def scan(self, t_s, tags, ranges, sigmas) -> tuple[int, int]:
        """Predict (eq. 11-12) to ``t_s`` and update with the scan (eq. 13-15).

        Returns (rows used, rows gated).
        """
        dt = max(t_s - self.t, 0.0)
        self.t = max(self.t, t_s)
        x, F = vehicle.random_walk(self.x, dt)
        self.x, self.P = ekf.predict(x, F, self.P, vehicle.random_walk_noise(2, self.cfg.speed_sigma_mps, dt))
        r_pred, H, ok = _gated_range_rows(self.x, self.P, tags, ranges, sigmas, self.cfg.range_gate_probability)
        if ok.any():
            tags_ok = tags[ok]
            self.x, self.P, _ = ekf.iterated_update(
                self.x, self.P, ranges[ok], lambda x: meas.tag_range(x, tags_ok), sigmas[ok] ** 2, self.cfg.update_iterations
            )
        return int(ok.sum()), int((~ok).sum())


class RfidEkf(FilterEstimator):
    """song2016 RFID-EKF (eq. 10-15): position random walk, one range row per
    detected tag, one output per RFID scan (1 Hz), no velocity.

    It starts from the user's start pose when one is given, else at the
    centroid of the first scan's tags with a 10 m sigma (the papers start it
    from DGPS, which this RFID-only filter does not read).
    """

    name = "rfid-ekf"
    summary = "song2016 RFID-EKF: 2-state EKF on tag ranges, output per scan (1 Hz), no velocity"
    required_channels = ("rfid",)
    output_on_scan = True
    needs_start = False
    config: RfidEkfConfig

    @classmethod
    def default_config(cls) -> RfidEkfConfig:
        return RfidEkfConfig()

    def _init_filter(self, drive, start):
        self._f = None if start is None else _RfidEkfState(self.config, np.array([start.east_m, start.north_m]), start.t_s, start.position_sigma_m)

    def _on_scan(self, t_s, tags, ranges, sigmas):
        if self._f is None:
            self._f = _RfidEkfState(self.config, tags.mean(axis=0), t_s, sigma0_m=10.0)
        used, gated = self._f.scan(t_s, tags, ranges, sigmas)
        self.diagnostics["ranges_used"] += used
        self.diagnostics["ranges_gated"] += gated
        f = self._f
        self._emit_scan_output(OutputRow(t_s, float(f.x[0]), float(f.x[1]), cov_en_m2=f.P.copy()))


class Multilateration(FilterEstimator):
    """Multilateration, song2016 eq. 38, by linearised least squares.

    Eq. 38 prints ``(x - x_i^2)^2``; the tag coordinates are not squared:
    ``r_i^2 = (x - x_i)^2 + (y - y_i)^2``. Subtracting the mean of the
    equations removes the quadratic terms and leaves the linear system
    ``2 (x_i - x_bar) x + 2 (y_i - y_bar) y = (|t_i|^2 - mean|t|^2) - (r_i^2 - mean r^2)``,
    solved by least squares at each scan with at least ``min_tags`` tags.
    The covariance given is ``(H^T R^-1 H)^-1`` of the ranges at the fix.
    """

    name = "multilateration"
    summary = "song2016 eq. 38 multilateration (linearised least squares), output per scan"
    required_channels = ("rfid",)
    output_on_scan = True
    needs_start = False
    config: MultilaterationConfig

    @classmethod
    def default_config(cls) -> MultilaterationConfig:
        return MultilaterationConfig()

    def _on_scan(self, t_s, tags, ranges, sigmas):
        if len(ranges) < max(self.config.min_tags, 3):
            self.diagnostics["scans_too_few_tags"] = self.diagnostics.get("scans_too_few_tags", 0) + 1
            return
        fix = multilaterate(tags, ranges)
        if fix is None:
            self.diagnostics["scans_degenerate"] = self.diagnostics.get("scans_degenerate", 0) + 1
            return
        _, H = meas.tag_range(fix, tags)
        info = H.T @ (H / (sigmas * sigmas)[:, None])
        cov = np.linalg.pinv(info)
        self.diagnostics["ranges_used"] += len(ranges)
        self._emit_scan_output(OutputRow(t_s, float(fix[0]), float(fix[1]), cov_en_m2=cov))


def multilaterate(tags_en_m: np.ndarray, ranges_m: np.ndarray) -> np.ndarray | None:
    """Linearised least-squares position from ranges (song2016 eq. 38, corrected).

    Returns None when the tags are (nearly) collinear.
    """
    t = np.asarray(tags_en_m, dtype=np.float64)
    r = np.asarray(ranges_m, dtype=np.float64)
    A = 2.0 * (t - t.mean(axis=0))
    sq = (t * t).sum(axis=1)
    b = (sq - sq.mean()) - (r * r - (r * r).mean())
    sv = np.linalg.svd(A, compute_uv=False)
    if sv.size < 2 or sv[1] < 1e-6 * max(sv[0], 1e-12):
        return None
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return sol


class _FusionInterval:
    """What the FUKF's local filters have yet to process since the last fusion.

    Attributes
    ----------
    dt_s, u, has_accel : lists
        The held IMU steps (length, input ``[a_x, a_y, w_z]``, accelerometers present).
    wheel_at, wheel_mps : lists
        Wheel speeds, each with the number of steps taken before it.
    compass_at, compass_rad : lists
        Compass yaws, likewise.
    """

    __slots__ = ("dt_s", "u", "has_accel", "wheel_at", "wheel_mps", "compass_at", "compass_rad")

    def __init__(self):
        self.dt_s: list[float] = []
        self.u: list[tuple[float, float, float]] = []
        self.has_accel: list[bool] = []
        self.wheel_at: list[int] = []
        self.wheel_mps: list[float] = []
        self.compass_at: list[int] = []
        self.compass_rad: list[float] = []


class Fukf(FilterEstimator):
    """song2016 §5 federated UKF.

    Two local UKFs on the eq. 16 model, both predicted with the IMU: local
    filter 1 observes the ranges (eq. 19), local filter 2 the wheel speed and
    compass (eq. 20). The master (beta_m = 0, no state of its own) fuses them
    (eq. 36-37) at every output epoch and after every RFID scan, then resets
    both to the fused state with ``P_j = P_g / beta_j``, ``Q_j = Q / beta_j``
    (eq. 34-35). The beta rule of §5.4: fewer than ``many_tags`` tags used in
    the scan -> ``beta_few_tags`` else ``beta_many_tags``; a fusion without a
    scan counts zero tags.

    Processing between fusions (deviations from a UKF step per IMU sample
    and per reading, both for speed: 100 Hz of unscented transforms in numpy
    ran at about 100x real time, issue 4 asks for 200x; this runs at about
    400x):

    * **Prediction over a fusion interval in one unscented transform.** Each
      local filter's sigma points are drawn once, at the last fusion (both
      filters are then at the fused state), and carried through every held
      IMU step since — eq. 16 applied step by step, in closed form over the
      steps (:func:`_propagate_steps`); the process noise of the whole
      interval, ``Q(T) / beta_j`` (:func:`_process_noise`; the
      no-accelerometer density if any step lacked them), is added at its
      end. Drawing the points again after every 10 ms step changes the
      transform only through the model's nonlinearity in yaw over at most
      0.1 s.
    * **Local filter 2's readings of an interval in one update.** Its wheel
      speeds (with the zero-sideways pseudo-measurement when on) and compass
      yaws since the last fusion are stacked into one measurement vector,
      each predicted from the sigma points carried to its own time stamp,
      and applied in one unscented update at the fusion. For a linear model
      and linear readings this is exactly the sequential updates (the tests
      check it); here it differs in that the yaw-dependent wheel measurement
      is linearised (statistically) about the interval's prior rather than
      each reading's posterior, and a reading does not see the process
      noise accrued between the fusion and its time (under 0.1 s of it: a
      few per cent of the prior velocity and yaw variances). Measured on 30
      simulated paper drives (all patterns, 3 seeds, optimised layout): mean
      RMS 0.498 -> 0.500 m, mean NEES 0.915 -> 0.920. Outputs are produced
      only at fusions, so none is delayed.
    """

    name = "fukf"
    summary = "song2016 federated UKF: range UKF + wheel/compass UKF, federated fusion, 10 Hz"
    required_channels = ("imu", "wheel", "rfid")
    optional_channels = ("compass",)
    config: FukfConfig

    @classmethod
    def default_config(cls) -> FukfConfig:
        return FukfConfig()

    def _init_filter(self, drive, start):
        cfg = self.config
        x0, P0 = _initial_state(start)
        self._points = MerweScaledSigmaPoints(5, cfg.ukf_alpha, cfg.ukf_beta, cfg.ukf_kappa)
        self._hold = _InputHold(cfg)
        self._local = [UnscentedKalmanFilter(x0, P0, self._points, angle_states=(YAW,)) for _ in range(2)]
        self._interval = _FusionInterval()
        self._x, self._P = x0, P0
        self._set_beta(cfg.beta_few_tags)
        self._reset()
        self._R_wheel = _wheel_variances(cfg)
        self._R_wheel_stacked: dict[int, np.ndarray] = {}
        self._var_compass = cfg.compass_sigma_rad**2
        self.diagnostics.setdefault("fusions", 0)  # kept over a restart after an odometry gap

    def _set_beta(self, beta):
        self._beta = tuple(float(b) for b in beta)

    def _reset(self):
        """Information sharing (eq. 34-35) and local reset to the fused state."""
        shares = share_information(self._P, np.zeros((5, 5)), self._beta)
        for f, (P_j, _) in zip(self._local, shares):
            f.reset(self._x, P_j)

    def _fuse(self):
        self._catch_up()
        self._x, self._P = fuse([(f.x, f.P) for f in self._local], angle_states=(YAW,))
        self.diagnostics["fusions"] += 1

    def _predict_to(self, t_s):
        dt = t_s - self._t
        if dt > 0.0:
            iv = self._interval
            iv.dt_s.append(dt)
            iv.u.append(self._hold.u)
            iv.has_accel.append(self._hold.has_accel)

    def _on_imu(self, t_s, accel_x, accel_y, yaw_rate):
        self._hold.set(accel_x, accel_y, yaw_rate)

    def _on_wheel(self, t_s, speed_mps):
        iv = self._interval
        iv.wheel_at.append(len(iv.dt_s))
        iv.wheel_mps.append(speed_mps)

    def _on_compass(self, t_s, yaw_rad):
        iv = self._interval
        iv.compass_at.append(len(iv.dt_s))
        iv.compass_rad.append(yaw_rad)

    def _catch_up(self):
        """Predict both local filters over the steps since the last fusion and
        update local filter 2 with that interval's readings (see the class
        docstring): one sigma-point draw per filter, propagated together."""
        iv = self._interval
        if not (iv.dt_s or iv.wheel_at or iv.compass_at):
            return
        self._interval = _FusionInterval()
        dt_s, u, has_accel = np.array(iv.dt_s), np.array(iv.u).reshape(-1, 3), np.array(iv.has_accel, dtype=bool)
        wheel_at, wheel_mps, compass_at, compass_rad = iv.wheel_at, iv.wheel_mps, iv.compass_at, iv.compass_rad
        f1, f2 = self._local
        n_pts = 2 * 5 + 1
        sig = np.empty((2 * n_pts, 5))
        self._points.sigma_points(f1.x, f1.P, out=sig[:n_pts])
        self._points.sigma_points(f2.x, f2.P, out=sig[n_pts:])
        traj = _propagate_steps(sig, dt_s, u, has_accel)
        Q = _process_noise(self.config, float(dt_s.sum()), _accel_psd(self.config, bool(has_accel.all())))
        f1.predict_points(traj[:n_pts, -1], Q / self._beta[0])
        dx = f2.predict_points(traj[n_pts:, -1], Q / self._beta[1])
        if not (wheel_at or compass_at):
            return
        z, Z, R = [], [], []
        if wheel_at:
            if self._R_wheel.size == 1:
                z.append(np.array(wheel_mps))
                Z.append(meas.wheel_speed(traj[n_pts:, wheel_at], False)[0])
            else:  # rows [speed, sideways] per reading
                z_wheel = np.zeros(2 * len(wheel_at))
                z_wheel[::2] = wheel_mps
                z.append(z_wheel)
                Z.append(meas.body_velocity(traj[n_pts:, wheel_at], False)[0].reshape(n_pts, -1))
            R.append(self._wheel_variances(len(wheel_at)))
        n_wheel = sum(r.size for r in z)
        if compass_at:
            z.append(np.array(compass_rad))
            Z.append(meas.compass_yaw(traj[n_pts:, compass_at], False)[0])
            R.append(np.full(len(compass_at), self._var_compass))
        f2.update_points(
            np.concatenate(z), np.concatenate(Z, axis=1), dx, np.concatenate(R),
            angle_measurements=range(n_wheel, n_wheel + len(compass_at)),
        )

    def _wheel_variances(self, readings: int) -> np.ndarray:
        """The diagonal R of ``readings`` wheel readings stacked (one array per count, built once)."""
        R = self._R_wheel_stacked.get(readings)
        if R is None:
            R = self._R_wheel_stacked[readings] = np.tile(self._R_wheel, readings)
        return R

    def _on_scan(self, t_s, tags, ranges, sigmas):
        cfg = self.config
        sigmas = sigmas * cfg.range_sigma_scale
        # share the information by the beta rule for this scan's tag count
        self._fuse()
        self._set_beta(cfg.beta_many_tags if len(ranges) >= cfg.many_tags else cfg.beta_few_tags)
        self._reset()
        # gate against the fused estimate: the local filter's covariance is
        # inflated by 1 / beta_1 by design and would let outliers through
        _, _, ok = _gated_range_rows(self._x, self._P, tags, ranges, sigmas, cfg.range_gate_probability)
        self.diagnostics["ranges_gated"] += int((~ok).sum())
        self.diagnostics["ranges_used"] += int(ok.sum())
        if ok.any():
            tags_ok = tags[ok]
            self._local[0].update(ranges[ok], lambda S: meas.tag_range(S, tags_ok, False)[0], sigmas[ok] ** 2)
        self._fuse()
        self._set_beta(cfg.beta_few_tags)
        self._reset()

    def _output(self, t_s):
        self._fuse()
        self._set_beta(self.config.beta_few_tags)
        self._reset()
        x = self._x
        return OutputRow(t_s, float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4]), self._P[:2, :2].copy())


#: song2016 / song2016b estimators by name.
ESTIMATORS = {
    cls.name: cls for cls in (DeadReckoning, Multilateration, RfidEkf, FusionEkf, Fukf, TwoLevelEkf)
}
