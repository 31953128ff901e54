"""The two graph parameterisations: planar (Pose2) and inertial (Pose3 + velocity + bias).

Both expose the same small interface to :mod:`graphpos.graph.builder`: the
keys of a keyframe, its initial values and priors, the odometry factors
between two keyframes, and the absolute factors (tag/RSU range, position
fix, compass yaw). Only GTSAM built-in factors are used.

Conventions
-----------
The planar graph's Pose2 is ``(east, north, yaw)``. The inertial graph's
navigation frame is east-north-up, the body frame x forward, y left, z up.
GTSAM's ``PreintegrationParams.MakeSharedU(g)`` puts gravity at
``(0, 0, -g)`` in that frame, so an accelerometer at rest reads ``+g`` on its
z axis: the planar IMU's two accelerations are fed as the specific force
``(a_x, a_y, +g)`` and its yaw rate as ``(0, 0, w_z)``. A planar prior on
each keyframe (roll, pitch, height ~ 0) and a zero vertical velocity keep
the 3-D states in the plane.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, C, V, X

from graphpos.graph.config import GraphConfig
from graphpos.graph.odometry import OdometryDelta

GRAVITY_MPS2 = 9.81

#: The compass's frame ``C(0)``: its yaw is minus the compass bias (``reading = yaw + bias``); see :meth:`PlanarModel.compass_bias_factor`.
COMPASS_BIAS_KEY = C(0)
#: Sigma of the compass frame's components other than the bias, and of the compass factor's other than the yaw:
#: a keyframe 10 km from the origin whitens to 1e-3 there, nothing against the 1-2 degree compass sigma.
COMPASS_FRAME_FREE_SIGMA = 1e7
#: Sigma of the prior holding the compass frame's components other than the bias at zero.
COMPASS_FRAME_FIXED_SIGMA = 1e-6


@dataclass
class KeyframeState:
    """One keyframe's estimate in project terms (east-north, yaw from east)."""

    east_m: float
    north_m: float
    yaw_rad: float
    v_east_mps: float = 0.0
    v_north_mps: float = 0.0
    bias: np.ndarray | None = None  # accel(3) + gyro(3), inertial graph only

    def moved(self, pivot_east_m: float, pivot_north_m: float, turn_rad: float, to_east_m: float, to_north_m: float) -> "KeyframeState":
        """The state turned by ``turn_rad`` about a pivot, the pivot then moved to ``(to_east_m, to_north_m)``."""
        c, s = math.cos(turn_rad), math.sin(turn_rad)
        de, dn = self.east_m - pivot_east_m, self.north_m - pivot_north_m
        return KeyframeState(to_east_m + c * de - s * dn, to_north_m + s * de + c * dn, self.yaw_rad + turn_rad,
                             c * self.v_east_mps - s * self.v_north_mps, s * self.v_east_mps + c * self.v_north_mps, self.bias)


def robust(sigma: float | np.ndarray, config: GraphConfig, dim: int = 1, loss: str | None = None, k: float | None = None) -> gtsam.noiseModel.Base:
    """Gaussian noise with an M-estimator (default: the configured range loss).

    Used for ranges and fixes (``config.robust_loss``, ``robust_k``) and
    the compass (``compass_loss``, ``compass_robust_k``).
    """
    loss = config.robust_loss if loss is None else loss
    k = config.robust_k if k is None else k
    base = gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma)) if np.ndim(sigma) == 0 else gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma, dtype=float))
    if loss == "huber":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k), base)
    if loss == "cauchy":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(k), base)
    return base


def compass_noise(sigma: float | np.ndarray, config: GraphConfig, dim: int = 1) -> gtsam.noiseModel.Base:
    """The compass's noise: a magnetic disturbance (steel near the road) deflects
    many consecutive readings by the same tens of degrees, so a bounded
    influence per reading (Huber) still adds up; a redescending loss
    (Cauchy) lets the gyro carry the heading through it.

    Every compass factor of a drive has the same sigmas: one noise model
    (GTSAM's are immutable) is built per sigmas and loss and shared, not
    three pybind objects per reading (issue 19).
    """
    key = (tuple(np.atleast_1d(sigma).tolist()), dim, config.compass_loss, config.compass_robust_k)
    noise = _COMPASS_NOISE.get(key)
    if noise is None:
        noise = _COMPASS_NOISE[key] = robust(sigma, config, dim, config.compass_loss, config.compass_robust_k)
    return noise


#: :func:`compass_noise`'s models by (sigmas, dim, loss, k).
_COMPASS_NOISE: dict[tuple, gtsam.noiseModel.Base] = {}


def _scaled(delta: OdometryDelta, wheel_scale: float | None) -> tuple[float, float, np.ndarray]:
    """Delta translation and covariance with the wheel readings divided by ``wheel_scale``.

    None: as integrated, with the wheel-scale drift term. A scale: the
    white covariance, translation rows and columns divided by the scale.
    """
    if wheel_scale is None:
        return delta.dx_m, delta.dy_m, delta.cov
    d = np.array([1.0 / wheel_scale, 1.0 / wheel_scale, 1.0])
    return delta.dx_m / wheel_scale, delta.dy_m / wheel_scale, delta.white_cov * np.outer(d, d)


def _rot_en(yaw: float, cov_body_xy: np.ndarray) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    return R @ cov_body_xy @ R.T


#: Tight sigma of a known landmark (tag/RSU) position prior, m.
LANDMARK_SIGMA_M = 1e-2


class PlanarModel:
    """Pose2 keyframes ``X(k)``; tags as Point2 landmarks."""

    name = "planar"

    def __init__(self, config: GraphConfig):
        self.config = config

    def keyframe_keys(self, k: int) -> list[int]:
        return [X(k)]

    def first_keyframe_keys(self, k: int) -> list[int]:
        return []

    def start_segment(self, k: int) -> None:
        """Keyframe ``k`` begins a track (nothing to do: a Pose2 keyframe has no shared variables)."""

    def insert_values(self, values: gtsam.Values, k: int, state: KeyframeState) -> None:
        values.insert(X(k), gtsam.Pose2(state.east_m, state.north_m, state.yaw_rad))

    def prior_factors(self, k: int, state: KeyframeState, position_sigma_m: float, yaw_sigma_rad: float) -> list:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([position_sigma_m, position_sigma_m, yaw_sigma_rad]))
        return [gtsam.PriorFactorPose2(X(k), gtsam.Pose2(state.east_m, state.north_m, state.yaw_rad), noise)]

    def keyframe_factors(self, k: int, state: KeyframeState) -> list:
        return []

    def odometry_factors(self, k: int, delta: OdometryDelta, pim) -> list:
        """The wheel + gyro factor (always first, see :meth:`wheel_factor`)."""
        return [self.wheel_factor(k, delta)]

    def wheel_factor(self, k: int, delta: OdometryDelta, wheel_scale: float | None = None):
        """BetweenFactorPose2 of the delta; ``wheel_scale``: wheel readings divided by it, white covariance."""
        dx, dy, cov = _scaled(delta, wheel_scale)
        return gtsam.BetweenFactorPose2(X(k - 1), X(k), gtsam.Pose2(dx, dy, delta.dtheta_rad), gtsam.noiseModel.Gaussian.Covariance(cov))

    def body_translation(self, values: gtsam.Values, k: int) -> np.ndarray:
        """Translation from keyframe ``k - 1`` to ``k`` in ``k - 1``'s body frame."""
        rel = values.atPose2(X(k - 1)).between(values.atPose2(X(k)))
        return np.array([rel.x(), rel.y()])

    def landmark(self, key: int, east_m: float, north_m: float) -> tuple[list, object]:
        point = np.array([east_m, north_m])
        return [gtsam.PriorFactorPoint2(key, point, gtsam.noiseModel.Isotropic.Sigma(2, LANDMARK_SIGMA_M))], point

    def range_factor(self, k: int, landmark_key: int, range_m: float, noise) -> object:
        return gtsam.RangeFactor2D(X(k), landmark_key, range_m, noise)

    def fix_factor(self, k: int, east_m: float, north_m: float, noise) -> object:
        return gtsam.PoseTranslationPrior2D(X(k), gtsam.Pose2(east_m, north_m, 0.0), noise)

    def fix_dim(self) -> int:
        return 2

    def compass_factor(self, k: int, yaw_rad: float, sigma_rad: float) -> object:
        return gtsam.PoseRotationPrior2D(X(k), gtsam.Rot2(yaw_rad), compass_noise(sigma_rad, self.config))

    def compass_bias_factor(self, k: int, yaw_rad: float, sigma_rad: float) -> object:
        """The compass reading as keyframe ``k``'s yaw in the compass's frame :data:`COMPASS_BIAS_KEY`.

        ``BetweenFactorPose2(C, X(k))`` measures ``C^-1 X(k)``, whose angle is
        the yaw less the frame's: with the frame's yaw at minus the bias, the
        reading is ``yaw + bias`` (a compass deviated by its installation,
        the car's steel).
        The relative translation is left free (:data:`COMPASS_FRAME_FREE_SIGMA`),
        so the factor is the compass factor with one more unknown; GTSAM has
        no built-in factor between a pose's angle and a Rot2.
        """
        free = COMPASS_FRAME_FREE_SIGMA
        return gtsam.BetweenFactorPose2(COMPASS_BIAS_KEY, X(k), gtsam.Pose2(0.0, 0.0, yaw_rad),
                                        compass_noise(np.array([free, free, sigma_rad]), self.config, 3))

    def compass_bias_prior(self, sigma_rad: float) -> tuple[object, object]:
        """The compass frame's prior (bias zero +- ``sigma_rad``, its origin fixed) and its value there."""
        fixed = COMPASS_FRAME_FIXED_SIGMA
        value = gtsam.Pose2()
        return gtsam.PriorFactorPose2(COMPASS_BIAS_KEY, value, gtsam.noiseModel.Diagonal.Sigmas(np.array([fixed, fixed, sigma_rad]))), value

    @staticmethod
    def compass_bias(values: gtsam.Values) -> float:
        """The solved compass bias, rad."""
        return -values.atPose2(COMPASS_BIAS_KEY).theta()

    def predict(self, state: KeyframeState, delta: OdometryDelta, pim) -> KeyframeState:
        pose = gtsam.Pose2(state.east_m, state.north_m, state.yaw_rad).compose(gtsam.Pose2(delta.dx_m, delta.dy_m, delta.dtheta_rad))
        return self._state(pose, delta.mean_speed_mps)

    def read(self, source, k: int, speed_mps: float, with_bias: bool = True) -> KeyframeState:
        """Keyframe ``k`` from a smoother (or :class:`~graphpos.graph.smoothers.ValuesSource`); no bias to read."""
        return self._state(source.calculateEstimatePose2(X(k)), speed_mps)

    @staticmethod
    def _state(pose: gtsam.Pose2, speed_mps: float) -> KeyframeState:
        yaw = pose.theta()
        return KeyframeState(pose.x(), pose.y(), yaw, speed_mps * math.cos(yaw), speed_mps * math.sin(yaw))

    def position(self, values: gtsam.Values, k: int) -> tuple[float, float]:
        """East, north of keyframe ``k`` in solved values."""
        pose = values.atPose2(X(k))
        return pose.x(), pose.y()

    def yaw(self, values: gtsam.Values, k: int) -> float:
        """Yaw of keyframe ``k`` in solved values."""
        return values.atPose2(X(k)).theta()

    def pose_key(self, k: int) -> int:
        return X(k)

    def position_cov(self, marginal: np.ndarray, state: KeyframeState) -> np.ndarray:
        """East/north covariance from a Pose2 marginal (tangent: body x, y, theta)."""
        return _rot_en(state.yaw_rad, marginal[:2, :2])


class InertialModel:
    """Pose3 ``X(k)`` and velocity ``V(k)`` per keyframe; IMU bias ``B(b)`` once per :attr:`BIAS_EVERY` keyframes.

    Between keyframes an ImuFactor with the bias in effect (``bias_key``);
    consecutive bias nodes are tied by a BetweenFactorConstantBias with the
    bias random walk over their interval. A bias node per keyframe (GTSAM's
    CombinedImuFactor) made 15 unknowns per keyframe; the biases drift over
    minutes, so one node per second loses nothing and leaves 9.6. A track
    that begins after an odometry gap (:meth:`start_segment`) begins with a
    bias node of its own.
    """

    name = "inertial"

    #: Sigmas of the planar prior: roll, pitch (rad) and height (m).
    PLANE_TILT_SIGMA_RAD = 0.01
    PLANE_HEIGHT_SIGMA_M = 0.01
    #: Loose sigma on everything the planar prior does not constrain.
    FREE_SIGMA = 1e3
    #: Yaw sigma of the wheel-odometry factor: loose, the IMU factor carries the gyro.
    ODOMETRY_YAW_SIGMA_RAD = 0.1
    #: Position integration variance density of the IMU preintegration, m^2/s.
    #: 1e-4 was enough with CombinedImuFactor, whose covariance also carries
    #: the bias walk; the plain ImuFactor's is stiffer, and with 1e-4 a 24 s
    #: tag blackout at 80 km/h (long-tunnel) made the system indeterminate.
    INTEGRATION_VARIANCE_M2PS = 1e-3
    #: Keyframes per IMU-bias node.
    BIAS_EVERY = 10
    #: Accelerometer noise density of an interval without accelerometer
    #: samples (m/s^2/sqrt(Hz)): zero body acceleration is integrated
    #: instead, with a density that covers a car's accelerations (a few
    #: m/s^2 in braking and turns: 3 m/s^2 sustained for a second is well
    #: inside 3 sigma), so the wheel factor carries the velocity.
    UNMEASURED_ACCEL_DENSITY = 3.0

    def __init__(self, config: GraphConfig, has_wheel_speed: bool = True):
        self.config = config
        self.has_wheel_speed = has_wheel_speed
        self.accel_density = config.accel_sigma_mps2 / math.sqrt(config.imu_rate_hz)
        self.bias_walk_density = np.array([config.accel_bias_walk_mps2_per_sqrt_s] * 3 + [config.gyro_bias_walk_radps_per_sqrt_s] * 3)
        self._segment_starts = [0]
        self.vertical_velocity_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([self.FREE_SIGMA, self.FREE_SIGMA, config.lateral_slip_sigma_mps]))
        self.plane_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([self.PLANE_TILT_SIGMA_RAD, self.PLANE_TILT_SIGMA_RAD, self.FREE_SIGMA, self.FREE_SIGMA, self.FREE_SIGMA, self.PLANE_HEIGHT_SIGMA_M])
        )

    def _preintegration_params(self, accel_density: float, extra_yaw_rate_var: float) -> gtsam.PreintegrationParams:
        """GTSAM's preintegration parameters: an accelerometer noise density (m/s^2/sqrt(Hz)), and the yaw rate's
        variance density beyond the gyro's white noise (rad^2/s; :meth:`preintegrate`)."""
        params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY_MPS2)
        gyro_density = self.config.gyro_sigma_radps / math.sqrt(self.config.imu_rate_hz)
        params.setAccelerometerCovariance(np.eye(3) * accel_density**2)
        params.setGyroscopeCovariance(np.diag([gyro_density**2, gyro_density**2, gyro_density**2 + extra_yaw_rate_var]))
        # Position integration noise (m^2/s): the planar IMU ignores road grade
        # and body roll, a model error far larger than GTSAM's usual 1e-8. It
        # also keeps the IMU factor's position block from being so stiff that
        # a long tag gap makes iSAM2's Cholesky indeterminate.
        params.setIntegrationCovariance(np.eye(3) * self.INTEGRATION_VARIANCE_M2PS)
        return params

    def start_segment(self, k: int) -> None:
        """Keyframe ``k`` begins a track (the drive's first, or one after an odometry gap): it gets a bias node of its own.

        A track that replaces one forgotten from the same keyframe on
        (never started, :meth:`GraphBuilder._end_segment`) replaces its start.
        """
        while self._segment_starts and self._segment_starts[-1] >= k:
            self._segment_starts.pop()
        self._segment_starts.append(k)

    def keyframe_keys(self, k: int) -> list[int]:
        return [X(k), V(k), B(k)] if self.bias_key(k) == B(k) else [X(k), V(k)]

    def bias_key(self, k: int) -> int:
        """The bias node in effect from keyframe ``k`` to ``k + 1``: every :attr:`BIAS_EVERY` keyframes, and at a track's start."""
        first = self._segment_starts[bisect.bisect_right(self._segment_starts, k) - 1]
        return B(max(k - k % self.BIAS_EVERY, first))

    def first_keyframe_keys(self, k: int) -> list[int]:
        """Keys beyond :meth:`keyframe_keys` that the graph's first keyframe needs: its bias node."""
        return [] if self.bias_key(k) == B(k) else [self.bias_key(k)]

    @staticmethod
    def _pose(state: KeyframeState) -> gtsam.Pose3:
        return gtsam.Pose3(gtsam.Rot3.Yaw(state.yaw_rad), np.array([state.east_m, state.north_m, 0.0]))

    def insert_values(self, values: gtsam.Values, k: int, state: KeyframeState) -> None:
        values.insert(X(k), self._pose(state))
        values.insert(V(k), np.array([state.v_east_mps, state.v_north_mps, 0.0]))
        if self.bias_key(k) == B(k):
            self.insert_bias(values, k, state)

    def insert_bias(self, values: gtsam.Values, k: int, state: KeyframeState) -> None:
        """The value of keyframe ``k``'s bias node."""
        values.insert(self.bias_key(k), gtsam.imuBias.ConstantBias(*self._bias_parts(state.bias)))

    @staticmethod
    def _bias_parts(bias: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        if bias is None:
            return np.zeros(3), np.zeros(3)
        return np.asarray(bias[:3], dtype=float), np.asarray(bias[3:], dtype=float)

    def prior_factors(self, k: int, state: KeyframeState, position_sigma_m: float, yaw_sigma_rad: float) -> list:
        c = self.config
        pose_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([self.PLANE_TILT_SIGMA_RAD, self.PLANE_TILT_SIGMA_RAD, yaw_sigma_rad, position_sigma_m, position_sigma_m, self.PLANE_HEIGHT_SIGMA_M])
        )
        bias_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([c.accel_bias_sigma_mps2] * 3 + [c.gyro_bias_sigma_radps] * 3))
        speed_sigma = max(10.0, position_sigma_m)
        return [
            gtsam.PriorFactorPose3(X(k), self._pose(state), pose_noise),
            gtsam.PriorFactorVector(V(k), np.array([state.v_east_mps, state.v_north_mps, 0.0]), gtsam.noiseModel.Isotropic.Sigma(3, speed_sigma)),
            gtsam.PriorFactorConstantBias(self.bias_key(k), gtsam.imuBias.ConstantBias(), bias_noise),
        ]

    def keyframe_factors(self, k: int, state: KeyframeState) -> list:
        """Planar prior (roll, pitch, height ~ 0) and zero vertical velocity.

        The prior's mean takes the keyframe's predicted yaw and east/north,
        whose sigmas are free, so the rotation log map sees small angles.
        """
        return [
            gtsam.PriorFactorPose3(X(k), self._pose(state), self.plane_noise),
            gtsam.PriorFactorVector(V(k), np.zeros(3), self.vertical_velocity_noise),
        ]

    def odometry_factors(self, k: int, delta: OdometryDelta, pim) -> list:
        """ImuFactor plus the wheel odometry as a BetweenFactorPose3 (and the bias walk at a new bias node).

        The between factor's translation carries the wheel speed and the
        non-holonomic constraint (small lateral/vertical sigma); its yaw is
        loose so the gyro, already in the IMU factor, is not counted twice.
        """
        factors = [self.wheel_factor(k, delta), gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), self.bias_key(k - 1), pim)]
        if self.bias_key(k) != self.bias_key(k - 1):
            walk = gtsam.noiseModel.Diagonal.Sigmas(self.bias_walk_density * math.sqrt(self.BIAS_EVERY / self.config.keyframe_rate_hz))
            factors.append(gtsam.BetweenFactorConstantBias(self.bias_key(k - 1), B(k), gtsam.imuBias.ConstantBias(), walk))
        return factors

    def wheel_factor(self, k: int, delta: OdometryDelta, wheel_scale: float | None = None):
        """The wheel odometry's BetweenFactorPose3 (``wheel_scale`` as in :class:`PlanarModel`).

        Without wheel speed (an IMU and ranges: an indoor UWB run) it keeps
        only the non-holonomic constraint: the forward translation gets
        :attr:`FREE_SIGMA`. The odometry's own stand-in for an unmeasured
        speed (held at 0 with 5 m/s, right for the planar graph, which has no
        velocity) would pull the IMU's velocity towards a standstill: on a
        synthetic 5 m/s drive the causal speed stayed 4.7 m/s and the error
        0.4-1.0 m, against 0.26 m for the RFID-only EKF.
        """
        dx, dy, planar_cov = _scaled(delta, wheel_scale)
        cov = np.zeros((6, 6))
        cov[0, 0] = cov[1, 1] = self.PLANE_TILT_SIGMA_RAD**2
        cov[2, 2] = self.ODOMETRY_YAW_SIGMA_RAD**2
        cov[3:5, 3:5] = planar_cov[:2, :2]
        if not self.has_wheel_speed:
            cov[3, 3], cov[3, 4], cov[4, 3] = self.FREE_SIGMA**2, 0.0, 0.0
        cov[5, 5] = max(planar_cov[1, 1], 1e-8)
        between = gtsam.Pose3(gtsam.Rot3.Yaw(delta.dtheta_rad), np.array([dx, dy, 0.0]))
        return gtsam.BetweenFactorPose3(X(k - 1), X(k), between, gtsam.noiseModel.Gaussian.Covariance(cov))

    def body_translation(self, values: gtsam.Values, k: int) -> np.ndarray:
        """Translation from keyframe ``k - 1`` to ``k`` in ``k - 1``'s body frame."""
        rel = values.atPose3(X(k - 1)).between(values.atPose3(X(k)))
        return np.asarray(rel.translation())[:2]

    def landmark(self, key: int, east_m: float, north_m: float) -> tuple[list, object]:
        point = np.array([east_m, north_m, 0.0])
        return [gtsam.PriorFactorPoint3(key, point, gtsam.noiseModel.Isotropic.Sigma(3, LANDMARK_SIGMA_M))], point

    def range_factor(self, k: int, landmark_key: int, range_m: float, noise) -> object:
        return gtsam.RangeFactor3D(X(k), landmark_key, range_m, noise)

    def fix_factor(self, k: int, east_m: float, north_m: float, noise) -> object:
        return gtsam.GPSFactor(X(k), np.array([east_m, north_m, 0.0]), noise)

    def fix_dim(self) -> int:
        return 3

    def compass_factor(self, k: int, yaw_rad: float, sigma_rad: float) -> object:
        noise = compass_noise(np.array([self.FREE_SIGMA, self.FREE_SIGMA, sigma_rad]), self.config, 3)
        return gtsam.PoseRotationPrior3D(X(k), gtsam.Rot3.Yaw(yaw_rad), noise)

    def compass_bias_factor(self, k: int, yaw_rad: float, sigma_rad: float) -> object:
        """The compass reading as keyframe ``k``'s yaw in the compass's frame (as :meth:`PlanarModel.compass_bias_factor`)."""
        free = COMPASS_FRAME_FREE_SIGMA
        noise = compass_noise(np.array([free, free, sigma_rad, free, free, free]), self.config, 6)
        return gtsam.BetweenFactorPose3(COMPASS_BIAS_KEY, X(k), gtsam.Pose3(gtsam.Rot3.Yaw(yaw_rad), np.zeros(3)), noise)

    def compass_bias_prior(self, sigma_rad: float) -> tuple[object, object]:
        """The compass frame's prior (bias zero +- ``sigma_rad``, the rest fixed) and its value there."""
        fixed = COMPASS_FRAME_FIXED_SIGMA
        value = gtsam.Pose3()
        sigmas = np.array([fixed, fixed, sigma_rad, fixed, fixed, fixed])
        return gtsam.PriorFactorPose3(COMPASS_BIAS_KEY, value, gtsam.noiseModel.Diagonal.Sigmas(sigmas)), value

    @staticmethod
    def compass_bias(values: gtsam.Values) -> float:
        """The solved compass bias, rad."""
        return -values.atPose3(COMPASS_BIAS_KEY).rotation().yaw()

    def predict(self, state: KeyframeState, delta: OdometryDelta, pim) -> KeyframeState:
        nav = gtsam.NavState(self._pose(state), np.array([state.v_east_mps, state.v_north_mps, 0.0]))
        bias = gtsam.imuBias.ConstantBias(*self._bias_parts(state.bias))
        pred = pim.predict(nav, bias)
        # Keep the prediction planar and use the wheel odometry for position.
        pose = self._pose(state).compose(gtsam.Pose3(gtsam.Rot3.Yaw(delta.dtheta_rad), np.array([delta.dx_m, delta.dy_m, 0.0])))
        v = pred.velocity()
        yaw = pred.attitude().yaw()
        return KeyframeState(pose.x(), pose.y(), yaw, float(v[0]), float(v[1]), state.bias)

    def read(self, source, k: int, speed_mps: float, with_bias: bool = True) -> KeyframeState:
        """Keyframe ``k`` from a smoother (or :class:`~graphpos.graph.smoothers.ValuesSource`).

        ``with_bias=False`` leaves the bias unread (None): a fixed-lag
        smoother may already have marginalised the bias node of a keyframe
        still in its window (the node is as old as its first keyframe).
        """
        pose = source.calculateEstimatePose3(X(k))
        v = source.calculateEstimateVector(V(k))
        bias = None
        if with_bias:
            b = source.calculateEstimateConstantBias(self.bias_key(k))
            bias = np.concatenate([b.accelerometer(), b.gyroscope()])
        return KeyframeState(pose.x(), pose.y(), pose.rotation().yaw(), float(v[0]), float(v[1]), bias)

    def position(self, values: gtsam.Values, k: int) -> tuple[float, float]:
        """East, north of keyframe ``k`` in solved values."""
        t = values.atPose3(X(k)).translation()
        return float(t[0]), float(t[1])

    def yaw(self, values: gtsam.Values, k: int) -> float:
        """Yaw of keyframe ``k`` in solved values."""
        return values.atPose3(X(k)).rotation().yaw()

    def pose_key(self, k: int) -> int:
        return X(k)

    def position_cov(self, marginal: np.ndarray, state: KeyframeState) -> np.ndarray:
        """East/north covariance from a Pose3 marginal (tangent: rotation, then body translation)."""
        return _rot_en(state.yaw_rad, marginal[3:5, 3:5])

    def preintegrate(self, samples: list[tuple[np.ndarray, np.ndarray, float, bool]], bias: np.ndarray | None,
                     extra_yaw_rate_var: float) -> gtsam.PreintegratedImuMeasurements:
        """One keyframe interval's IMU samples preintegrated at ``bias``.

        ``samples``: (specific force (3,), angular rate (3,), dt, whether the
        accelerometers were measured) per held step. An interval with an
        unmeasured step takes :attr:`UNMEASURED_ACCEL_DENSITY` (wide
        accelerometer noise) throughout.

        ``extra_yaw_rate_var``: the yaw rate's variance density beyond the
        gyro's white noise over the interval, rad^2/s: the heading noise and
        turn-rate scale terms the planar odometry adds to its turn
        (:class:`~graphpos.graph.odometry.PlanarOdometry`'s
        ``heading_density`` and ``turn_scale_density``), which a sensor
        profile sets (:meth:`GraphBuilder._imu_turn_noise_var`). Without it the IMU factor, which
        carries the inertial graph's heading, held the gyro to its white
        noise whatever the profile said: where the yaw rate reads 29 % off
        (a ``realistic`` drive's U-turn outside the tunnel, before any
        learning had seen a turn) graph-isam2's heading followed the gyro
        58 degrees away from a compass good to 1 degree, which the compass's
        redescending loss then ignored (realistic paper-straight seed 0:
        4.37 m RMS, 0.18 m with it).
        """
        measured = all(m for *_, m in samples)
        params = self._preintegration_params(self.accel_density if measured else self.UNMEASURED_ACCEL_DENSITY, extra_yaw_rate_var)
        pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias(*self._bias_parts(bias)))
        for force, rate, dt, _ in samples:
            pim.integrateMeasurement(force, rate, dt)
        return pim


def make_model(config: GraphConfig, has_accelerometers: bool, has_wheel_speed: bool = True):
    """The configured parameterisation (``auto``: inertial iff accelerometers)."""
    kind = config.parameterisation
    if kind == "auto":
        kind = "inertial" if has_accelerometers else "planar"
    return InertialModel(config, has_wheel_speed) if kind == "inertial" else PlanarModel(config)
