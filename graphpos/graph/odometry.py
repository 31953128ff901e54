"""Wheel speed + yaw rate preintegrated between two keyframes.

The vehicle moves along its body x axis at the wheel speed ``v`` and turns
at the gyro's yaw rate ``w``; both are held constant between samples
(zero-order hold, the value of the latest sample). Over one keyframe
interval this gives the relative pose ``(dx, dy, dtheta)`` in the first
keyframe's body frame, and its covariance from first-order propagation of
the wheel-speed noise, the gyro noise and a lateral-slip noise (the
non-holonomic constraint's softness). The result becomes a
``BetweenFactorPose2`` (planar graph) or a ``BetweenFactorPose3`` (inertial
graph, where it carries the wheel speed and the non-holonomic constraint).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OdometryDelta:
    """Relative pose over one keyframe interval.

    ``dx_m, dy_m`` in the first keyframe's body frame (x forward, y left),
    ``dtheta_rad`` counter-clockwise; ``cov`` is the 3x3 covariance of
    ``(dx, dy, dtheta)``; ``white_cov`` the same without the wheel-scale
    drift term (for a graph whose wheel scale is estimated);
    ``mean_speed_mps`` the mean wheel speed; ``drift_cov_per_density2`` the
    drift term for a unit wheel-scale density (``cov = white_cov +
    density**2 * drift_cov_per_density2``), to rebuild ``cov`` with another
    density.
    """

    dx_m: float
    dy_m: float
    dtheta_rad: float
    cov: np.ndarray
    duration_s: float
    mean_speed_mps: float
    white_cov: np.ndarray
    drift_cov_per_density2: np.ndarray

    def with_turn_density(self, extra_density2: float) -> "OdometryDelta":
        """The same delta with ``extra_density2 * dtheta^2 / duration`` more heading variance (a looser turn-rate scale)."""
        extra = np.zeros((3, 3))
        extra[2, 2] = extra_density2 * self.dtheta_rad**2 / max(self.duration_s, 1e-9)
        return dataclasses.replace(self, cov=self.cov + extra, white_cov=self.white_cov + extra)

    def with_drift_density(self, density_per_sqrt_s: float) -> "OdometryDelta":
        """The same delta with the wheel-scale drift term of another density."""
        return dataclasses.replace(self, cov=self.white_cov + density_per_sqrt_s**2 * self.drift_cov_per_density2)


class PlanarOdometry:
    """Accumulates wheel and gyro samples and cuts them into keyframe deltas.

    Parameters
    ----------
    speed_density : float
        Wheel-speed white-noise density, m/s * sqrt(s)
        (per-sample sigma / sqrt(rate)).
    yaw_rate_density : float
        Gyro white-noise density, rad/s * sqrt(s).
    slip_density : float
        Lateral body-velocity density, m/s * sqrt(s).
    heading_drift_sigma_radps : float
        Extra heading variance growth (rad/s)^2 * s per interval second.
    speed_scale_density : float
        Density of a white relative speed error, 1/sqrt(s): adds
        ``(density * v)^2`` (m/s)^2 * s to the speed's variance growth. It
        stands for the wheel's scale error (about 1 %, constant over a
        drive), which white per-sample noise cannot cover: its along-track
        drift grows with the distance driven, not with the sample count,
        so this term is the same at any wheel rate (Plaza 5 Hz, sim 100 Hz).
    heading_density : float
        White heading noise density beyond the gyro's, rad/sqrt(s): heading
        variance grows by its square per second, whatever the sample rate
        (the residual heading noise :func:`graphpos.graph.calibration.fit_profile`
        measures).
    turn_scale_density : float
        Density of a relative turn-rate error, 1/sqrt(s): adds
        ``(density * w)^2`` (rad/s)^2 * s to the heading's variance growth, for
        a turn-rate sensor whose scale is off (odometry turn rates several
        per cent off; like ``speed_scale_density``, independent of the rate).
    has_speed, has_yaw_rate : bool
        Whether the drive gives wheel speed / yaw rate. Without wheel speed
        the speed is unknown (held at 0 with a large sigma); without a gyro
        the heading change is left to the compass (large sigma).
    """

    #: Sigma used for a quantity the drive does not measure.
    UNMEASURED_SPEED_SIGMA_MPS = 5.0
    UNMEASURED_YAW_RATE_SIGMA_RADPS = 1.0

    def __init__(
        self,
        speed_density: float,
        yaw_rate_density: float,
        slip_density: float,
        heading_drift_sigma_radps: float,
        speed_scale_density: float = 0.0,
        heading_density: float = 0.0,
        turn_scale_density: float = 0.0,
        has_speed: bool = True,
        has_yaw_rate: bool = True,
    ):
        self.speed_var = speed_density**2
        self.yaw_rate_var = yaw_rate_density**2
        self.slip_var = slip_density**2
        self.drift_var = heading_drift_sigma_radps**2
        self.scale_var = speed_scale_density**2
        self.turn_scale_var = turn_scale_density**2
        self.heading_var = heading_density**2
        self.has_speed = has_speed
        self.has_yaw_rate = has_yaw_rate
        self.speed_mps = 0.0
        self.yaw_rate_radps = 0.0
        self._t_s: float | None = None
        self._dt: list[float] = []
        self._v: list[float] = []
        self._w: list[float] = []

    # -- samples --------------------------------------------------------------
    def start(self, t_s: float) -> None:
        """Begin integrating at ``t_s`` (a new track: anything integrated before is dropped)."""
        self._t_s = t_s
        self._dt, self._v, self._w = [], [], []

    def set_speed(self, speed_mps: float) -> None:
        self.speed_mps = speed_mps

    def set_yaw_rate(self, yaw_rate_radps: float) -> None:
        self.yaw_rate_radps = yaw_rate_radps

    def advance(self, t_s: float) -> None:
        """Integrate the held speed and yaw rate up to ``t_s``."""
        if self._t_s is None:
            self._t_s = t_s
            return
        dt = t_s - self._t_s
        if dt > 0:
            self._dt.append(dt)
            self._v.append(self.speed_mps)
            self._w.append(self.yaw_rate_radps)
            self._t_s = t_s

    # -- keyframes ------------------------------------------------------------
    def cut(self, t_s: float) -> OdometryDelta:
        """Integrate up to ``t_s`` and return the delta since the last cut."""
        self.advance(t_s)
        dt = np.asarray(self._dt)
        v = np.asarray(self._v)
        w = np.asarray(self._w)
        self._dt, self._v, self._w = [], [], []
        unit_scale_var = v**2 / np.maximum(dt, 1e-9) if self.has_speed else np.zeros(dt.shape)
        return integrate(dt, v, w, self._variances(dt, w), unit_scale_var, self.scale_var)

    def _variances(self, dt: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-segment variances of (speed, yaw rate, lateral speed), white noise held over dt."""
        safe = np.maximum(dt, 1e-9)
        sv = self.speed_var / safe if self.has_speed else np.full(dt.shape, self.UNMEASURED_SPEED_SIGMA_MPS**2)
        if self.has_yaw_rate:
            sw = (self.yaw_rate_var + self.heading_var + self.turn_scale_var * w * w) / safe
        else:
            sw = np.full(dt.shape, self.UNMEASURED_YAW_RATE_SIGMA_RADPS**2)
        return sv, sw + self.drift_var, self.slip_var / safe


#: Floor added to the delta covariance so a stationary interval stays invertible.
_COV_FLOOR = np.diag([1e-8, 1e-8, 1e-10])


def integrate(
    dt_s: np.ndarray,
    speed_mps: np.ndarray,
    yaw_rate_radps: np.ndarray,
    variances: tuple[np.ndarray, np.ndarray, np.ndarray],
    unit_scale_variance: np.ndarray | None = None,
    scale_density2: float = 0.0,
) -> OdometryDelta:
    """Zero-order-hold unicycle integration with first-order covariance.

    Segment ``i`` lasts ``dt_i`` at speed ``v_i`` and yaw rate ``w_i``,
    starting at heading ``theta_i = sum_{j<i} w_j dt_j``. With
    ``p_end = sum_i v_i dt_i (cos theta_i, sin theta_i)``:
    ``d p_end / d v_i = dt_i (cos theta_i, sin theta_i)``,
    ``d p_end / d w_j = dt_j J (p_end - p_{j+1})`` (J: +90 degree rotation),
    ``d theta_end / d w_j = dt_j``, and a lateral speed error ``s_i`` moves
    the end by ``dt_i (-sin theta_i, cos theta_i)``. ``unit_scale_variance``
    (per segment, optional) is a further speed variance per unit wheel-scale
    density squared; ``scale_density2`` times it enters ``cov``, not
    ``white_cov``.
    """
    n = dt_s.shape[0]
    total = float(dt_s.sum())
    if n == 0:
        return OdometryDelta(0.0, 0.0, 0.0, _COV_FLOOR.copy(), 0.0, 0.0, _COV_FLOOR.copy(), np.zeros((3, 3)))
    theta_start = np.concatenate(([0.0], np.cumsum(yaw_rate_radps * dt_s)))
    theta = theta_start[:-1]
    c, s = np.cos(theta), np.sin(theta)
    step_e = speed_mps * dt_s * c
    step_n = speed_mps * dt_s * s
    p_after = np.column_stack([np.cumsum(step_e), np.cumsum(step_n)])
    p_end = p_after[-1]
    lever = p_end - p_after  # p_end - p_{j+1}
    G = np.zeros((3, 3 * n))
    G[0, 0::3] = dt_s * c
    G[1, 0::3] = dt_s * s
    G[0, 1::3] = -dt_s * lever[:, 1]
    G[1, 1::3] = dt_s * lever[:, 0]
    G[2, 1::3] = dt_s
    G[0, 2::3] = -dt_s * s
    G[1, 2::3] = dt_s * c
    q = np.empty(3 * n)
    q[0::3], q[1::3], q[2::3] = variances
    white = (G * q) @ G.T + _COV_FLOOR
    drift = np.zeros((3, 3)) if unit_scale_variance is None else (G[:, 0::3] * unit_scale_variance) @ G[:, 0::3].T
    mean_speed = float((speed_mps * dt_s).sum() / total) if total > 0 else 0.0
    return OdometryDelta(float(p_end[0]), float(p_end[1]), float(theta_start[-1]), white + scale_density2 * drift, total, mean_speed, white, drift)
