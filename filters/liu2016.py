"""liu2016: RSU/GNSS/DR integrated positioning with a federated Kalman filter.

Three local filters share the "current" statistical acceleration model
(:mod:`filters.models.kinematic`, liu2016 eq. 1-5, 16), state
``[x_e, v_e, a_e, x_n, v_n, a_n]``:

* LF1, linear KF on RSU position fixes (eq. 6, 11-15); an RSU reading that
  carries only a range is used as a range row (EKF), the one addition;
* LF2, linear KF on GNSS fixes (eq. 7, 11-15);
* LF3, EKF on the DR observation ``[omega, s]`` — gyro yaw rate and odometer
  distance over the step (eq. 8-10, 17), with the Jacobian derived in
  :func:`filters.models.kinematic.dr_observation` (yaw from east, not the
  paper's heading from north).

The master fuses them (eq. 18, :func:`filters.core.federated.fuse`) and
shares the information back (eq. 19, ``P_i = P_g / beta_i``,
``Q_i = Q / beta_i``, ``x_i = x_g``, :func:`filters.core.federated.share_information`).
Because the reset happens every step and the model is linear, sharing after
the time update is the same as sharing before it, so one prediction of the
global state serves the three local filters; local filters without a
measurement in a step hold that shared prediction, and enter the fusion as
one estimate with their summed share (the same information, fewer inverses).

Fault detection and isolation (liu2016 §3.2.2, not given as equations — the
project's design): every local measurement is tested against the global
prediction, ``nu^T (H P_g H^T + R)^-1 nu`` against the chi-square quantile
(``consistency_probability``, degrees of freedom = rows). A failing
measurement is not used; ``isolate_after`` consecutive failures isolate the
subsystem, and so does no data for ``no_data_timeout_s``. An isolated
subsystem takes no part in the fusion and its share ``beta_i`` is
redistributed over the others in proportion to theirs (they still sum to
one). It keeps being tested and is restored after ``recover_after``
consecutive passes (one pass after a no-data isolation). Isolation
intervals are reported in the diagnostics.

Timing: the filter steps at the output epochs (10 Hz; the multi-rate plumbing
is :class:`filters.base.FilterEstimator`'s) and at each GNSS/RSU fix, which
is applied at its own time; the gyro rate and wheel speed since the last
step are averaged into the DR observation (``s = mean speed * T``). The state starts from the drive's initial
pose, like every filter of the project.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from filters.base import FilterEstimator
from filters.core import ekf, federated
from filters.models import kinematic as km
from graphpos.drive import Drive
from graphpos.errors import ConfigError, MissingChannelError
from graphpos.estimate import Estimate, OutputRow
from graphpos.estimator import require_valid_numbers
from graphpos.ignition import StartState

SUBSYSTEMS = ("rsu", "gnss", "dr")
_POS = [km.XE, km.XN]
_NO_ANCHOR = np.zeros(0)


def _position_fix(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """liu2016 eq. (6)-(7): ``Z = H x`` with ``H`` the 6-state position rows."""
    return km.CS_POSITION_H @ x, km.CS_POSITION_H


@dataclass
class Liu2016Config:
    """Tunables of the liu2016 federated filter.

    Attributes
    ----------
    subsystems : tuple of {"rsu", "gnss", "dr"}
        Local filters to run (one alone gives the single-subsystem baseline).
    sharing : tuple of 3 float
        Information-sharing coefficients ``beta_1, beta_2, beta_3`` (RSU,
        GNSS, DR) before redistribution; normalised over the subsystems run.
    output_rate_hz : float
        Filter and output rate.
    accel_sigma_mps2 : float
        ``sigma_ae = sigma_an`` of the "current" statistical model.
    accel_tau_s : float
        ``tau_ae = tau_an``, correlation time of the manoeuvring acceleration.
    gyro_sigma_radps : float
        ``sigma_omega``, gyro noise of the step's mean rate.
    odometer_sigma_mps : float
        Wheel-speed 1-sigma; ``sigma_s = odometer_sigma_mps * T``. It covers
        the wheel's scale error (about 1 %, correlated from step to step),
        not only its white noise: a smaller value lets a scale error drag
        the fused track.
    dr_min_speed_mps : float
        Below this predicted speed the DR observation (singular at rest) is skipped.
    consistency_probability : float
        Chi-square probability of the fault test (1: no fault detection).
    isolate_after, recover_after : int
        Consecutive failures that isolate a subsystem, passes that restore it.
    no_data_timeout_s : float
        A subsystem silent this long is isolated.
    init_accel_sigma_mps2 : float
        Initial 1-sigma of the acceleration (the position, speed and heading
        sigmas come from ignition, :mod:`graphpos.ignition`).
    coast : bool
        Output while every subsystem is isolated (pure prediction). The
        single-subsystem baselines turn it off: a positioning system without
        data gives no position.
    """

    subsystems: tuple[str, ...] = SUBSYSTEMS
    sharing: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)
    output_rate_hz: float = 10.0
    accel_sigma_mps2: float = 1.0
    accel_tau_s: float = 5.0
    gyro_sigma_radps: float = 0.5 * math.pi / 180
    odometer_sigma_mps: float = 0.3
    dr_min_speed_mps: float = 1.0
    consistency_probability: float = 0.999
    isolate_after: int = 3
    recover_after: int = 3
    no_data_timeout_s: float = 3.0
    coast: bool = True
    init_accel_sigma_mps2: float = 1.0

    def __post_init__(self) -> None:
        require_valid_numbers(self, skip=("dr_min_speed_mps",))
        if self.dr_min_speed_mps < 0:
            raise ConfigError(f"dr_min_speed_mps must be >= 0, got {self.dr_min_speed_mps}")
        bad = [s for s in self.subsystems if s not in SUBSYSTEMS]
        if not self.subsystems or bad:
            raise ConfigError(f"liu2016 subsystems must be chosen from {SUBSYSTEMS}, got {self.subsystems}")
        if len(self.sharing) != 3 or any(b <= 0 for b in self.sharing):
            raise ConfigError("sharing needs three positive coefficients (RSU, GNSS, DR)")
        if not 0.0 < self.consistency_probability <= 1.0:
            raise ConfigError("consistency_probability must lie in (0, 1]")
        if self.output_rate_hz <= 0 or self.accel_tau_s <= 0:
            raise ConfigError("output_rate_hz and accel_tau_s must be positive")


@dataclass
class _Health:
    """Fault-detection state of one subsystem."""

    isolated: bool = False
    reason: str = ""
    fails: int = 0
    passes: int = 0
    last_data_s: float = -math.inf
    intervals: list = field(default_factory=list)
    rejected: int = 0
    tested: int = 0

    def isolate(self, t_s: float, reason: str) -> None:
        if not self.isolated:
            self.isolated, self.reason = True, reason
            self.intervals.append([t_s, None, reason])
            self.passes = 0

    def restore(self, t_s: float) -> None:
        self.isolated, self.reason, self.fails = False, "", 0
        self.intervals[-1][1] = t_s


class FederatedKf(FilterEstimator):
    """liu2016 federated KF over RSU fixes, GNSS fixes and DR (gyro + odometer)."""

    name = "fkf"
    summary = "liu2016 federated KF: RSU + GNSS linear KFs, DR EKF, information sharing, fault isolation (10 Hz)"
    #: The DR subsystem's channels (checked while "dr" is among the configured subsystems, as by default)
    #: and one kind of position fix (graphpos estimators: "needs imu, wheel, and rsu or gnss").
    required_channels = ("imu", "wheel")
    required_any = (("rsu", "gnss"),)
    optional_channels = ("rsu", "gnss")
    config: Liu2016Config

    @classmethod
    def default_config(cls) -> Liu2016Config:
        return Liu2016Config()

    def check(self, drive: Drive) -> None:
        subs = self.config.subsystems
        if not (drive.has("rsu") or drive.has("gnss")):
            raise MissingChannelError(f"{self.name} needs position fixes (rsu or gnss channel); drive '{drive.name}' has neither")
        if "dr" in subs and not (drive.has("imu") and drive.has("wheel")):
            raise MissingChannelError(f"{self.name}'s DR subsystem needs the imu and wheel channels, which drive '{drive.name}' lacks")

    # -- handlers ---------------------------------------------------------------
    def _init_filter(self, drive: Drive, start: StartState) -> None:
        """Start from ignition's start state (:mod:`graphpos.ignition`; the
        paper sets the DR start by hand)."""
        cfg = self.config
        t0_s = start.t_s
        self._dt = 1.0 / cfg.output_rate_hz
        self._rsus = {int(i): np.array([e, n]) for i, e, n in zip(drive.rsus.rsu_id, drive.rsus.east_m, drive.rsus.north_m)}
        self._Q = km.current_statistical_process_noise(self._dt, cfg.accel_sigma_mps2, cfg.accel_sigma_mps2, cfg.accel_tau_s, cfg.accel_tau_s)
        self._health = {s: _Health(last_data_s=t0_s) for s in cfg.subsystems}
        self._sharing = {s: cfg.sharing[SUBSYSTEMS.index(s)] for s in cfg.subsystems}
        self._x = np.array([start.east_m, start.v_east_mps, 0.0, start.north_m, start.v_north_mps, 0.0])
        sp, sv, sa = start.position_sigma_m, start.speed_sigma_mps, cfg.init_accel_sigma_mps2
        self._P = np.diag(np.square([sp, sv, sa, sp, sv, sa]))
        self._t_state = t0_s
        self._yaw = start.yaw_rad
        self._reset_epoch()

    def _reset_epoch(self) -> None:
        self._fixes: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {"rsu": [], "gnss": []}
        self._gyro: list[float] = []
        self._speed: list[float] = []

    def _on_imu(self, t_s, accel_x, accel_y, yaw_rate):
        self._gyro.append(yaw_rate)

    def _on_wheel(self, t_s, speed_mps):
        self._speed.append(speed_mps)

    def _on_fix(self, t_s, channel, values):
        """A fix is applied at its own time: the federated filter steps to it."""
        if channel == "gnss":
            east, north, sigma = values
            self._fixes["gnss"].append((np.array([east, north]), np.array([sigma**2, sigma**2]), _NO_ANCHOR))
        else:
            rsu_id, east, north, range_m, sigma = values
            if math.isfinite(east) and math.isfinite(north):
                self._fixes["rsu"].append((np.array([east, north]), np.array([sigma**2, sigma**2]), _NO_ANCHOR))
            elif math.isfinite(range_m):
                self._fixes["rsu"].append((np.array([range_m]), np.array([sigma**2]), self._rsus[int(rsu_id)]))
        self._step_to(t_s)

    def _step_to(self, t_s: float) -> None:
        fixes, gyro, speed = self._fixes, self._gyro, self._speed
        self._reset_epoch()
        self._step(t_s, fixes, gyro, speed)
        self._t_state = max(self._t_state, t_s)

    def _output(self, t_s: float) -> OutputRow | None:
        if t_s > self._t_state:
            self._step_to(t_s)
        if not self.config.coast and all(h.isolated for h in self._health.values()):
            return None
        x, P = self._x, self._P
        if math.hypot(x[km.CVE], x[km.CVN]) > self.config.dr_min_speed_mps:
            self._yaw = math.atan2(x[km.CVN], x[km.CVE])
        cov = P[np.ix_(_POS, _POS)].copy()
        return OutputRow(t_s, float(x[km.XE]), float(x[km.XN]), float(x[km.CVE]), float(x[km.CVN]), self._yaw, cov)

    def finish(self) -> Estimate:
        end = self._t_state
        subsystems = {}
        for name, h in self._health.items():
            intervals = [[a, b if b is not None else end, r] for a, b, r in h.intervals]
            subsystems[name] = {
                "isolations": intervals,
                "isolated_s": float(sum(b - a for a, b, _ in intervals)),
                "tested": h.tested,
                "rejected": h.rejected,
            }
        self.diagnostics["subsystems"] = subsystems
        return super().finish()

    @staticmethod
    def _fix_model(anchor: np.ndarray):
        """``x -> (h(x), H)`` of a position fix (eq. 6-7, ``anchor`` empty) or
        of a range to the RSU at ``anchor``."""
        if anchor.size == 0:
            return _position_fix

        def rsu_range(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            d = np.array([x[km.XE] - anchor[0], x[km.XN] - anchor[1]])
            r = max(float(np.hypot(*d)), 1e-6)
            H = np.zeros((1, 6))
            H[0, km.XE], H[0, km.XN] = d / r
            return np.array([r]), H

        return rsu_range

    # -- one step -----------------------------------------------------------------
    def _step(self, t_s: float, fixes: dict, gyro: list[float], speed: list[float]) -> None:
        cfg = self.config
        T = max(t_s - self._t_state, 0.0)
        Q = self._Q if abs(T - self._dt) < 1e-9 else km.current_statistical_process_noise(
            T, cfg.accel_sigma_mps2, cfg.accel_sigma_mps2, cfg.accel_tau_s, cfg.accel_tau_s)
        x_pred, Phi = km.current_statistical_prediction(self._x, T)  # eq. 16
        _, P_pred = ekf.predict(x_pred, Phi, self._P, Q)  # eq. 12
        # local measurements of this step: subsystem -> [(z, R diagonal, h)]
        local: dict[str, list] = {}
        for ch in ("rsu", "gnss"):
            if ch in self._health:
                local[ch] = [(z, R, self._fix_model(anchor)) for z, R, anchor in fixes[ch]]
        if "dr" in self._health:
            local["dr"] = []
            if T > 0 and gyro and speed and math.hypot(x_pred[km.CVE], x_pred[km.CVN]) > cfg.dr_min_speed_mps:
                z = np.array([sum(gyro) / len(gyro), sum(speed) / len(speed) * T])
                R = np.array([cfg.gyro_sigma_radps**2, (cfg.odometer_sigma_mps * T) ** 2])
                local["dr"].append((z, R, lambda x: km.dr_observation(x, T)))  # eq. 8-10
            elif gyro and speed:
                self._health["dr"].last_data_s = t_s  # data, unusable at this speed
        # fault detection against the global prediction
        accepted: dict[str, list] = {}
        for name, meas in local.items():
            h = self._health[name]
            accepted[name] = []
            for z, R, model in meas:
                h.last_data_s = t_s
                h.tested += 1
                zp, H = model(x_pred)
                nu = z - zp
                S = H @ P_pred @ H.T + np.diag(R)
                if float(nu @ np.linalg.solve(S, nu)) <= ekf.chi2_threshold(cfg.consistency_probability, z.size):
                    h.fails = 0
                    h.passes += 1
                    if h.isolated and (h.reason == "no data" or h.passes >= cfg.recover_after):
                        h.restore(t_s)
                    accepted[name].append((z, R, model))
                else:
                    h.rejected += 1
                    h.passes = 0
                    h.fails += 1
                    if h.fails >= cfg.isolate_after:
                        h.isolate(t_s, "inconsistent")
            if t_s - h.last_data_s > cfg.no_data_timeout_s:
                h.isolate(t_s, "no data")
        # information sharing (eq. 19) over the subsystems not isolated:
        # P_i = P_g / beta_i, with the isolated shares redistributed
        active = [n for n in cfg.subsystems if not self._health[n].isolated]
        if not active:
            self._x, self._P = x_pred, P_pred
            return
        total = sum(self._sharing[n] for n in active)
        estimates = []
        idle_share = 0.0
        for name in active:
            beta = self._sharing[name] / total
            if not accepted[name]:
                idle_share += beta
                continue
            x_i, P_i = x_pred, P_pred / beta
            for z, R, model in accepted[name]:  # eq. 13-15 / 17
                zp, H = model(x_i)
                upd = ekf.update(x_i, P_i, z, zp, H, R)
                x_i, P_i = upd.x, upd.P
            estimates.append((x_i, P_i))
        if idle_share > 0:
            # local filters without a measurement this step hold the shared
            # prediction; their information adds up to one estimate
            estimates.append((x_pred, P_pred / idle_share))
        self._x, self._P = federated.fuse(estimates)  # eq. 18


ESTIMATORS = {FederatedKf.name: FederatedKf}
