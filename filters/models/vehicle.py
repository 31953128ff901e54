"""Vehicle process models (song2016), with analytic Jacobians.

State order, shared by every 5-state estimator (and the first five entries of
the 6-state kinematic models of song2014)::

    x = [p_e, p_n, v_e, v_n, psi]      metres, m/s, radians (yaw from east, CCW)

Functions take ``x`` of shape ``(n,)`` or a stack ``(k, n)`` (sigma points)
and return ``(value, jacobian)``; ``jacobian=False`` skips the Jacobian
(``None`` is returned in its place), which the unscented filters use.
"""

from __future__ import annotations

import math

import numpy as np

#: Indices into the state vector.
PE, PN, VE, VN, YAW = 0, 1, 2, 3, 4


_IDENTITIES: dict[int, np.ndarray] = {}


def _identity(n: int) -> np.ndarray:
    """A fresh n x n identity (copied from a cached one: cheaper than np.eye)."""
    eye = _IDENTITIES.get(n)
    if eye is None:
        eye = _IDENTITIES[n] = np.eye(n)
    return eye.copy()


def improved_motion(x: np.ndarray, u: np.ndarray, dt_s: float, jacobian: bool = True, input_jacobian: bool = True):
    """song2016 eq. 16, the improved vehicle motion model, in state order.

    Parameters
    ----------
    x : (..., 5) array
        ``[p_e, p_n, v_e, v_n, psi]``.
    u : (3,) array
        Input ``[a_x, a_y, w_z]``: body accelerations (m/s^2) and yaw rate
        (rad/s), held constant over the step.
    dt_s : float
        Step T.
    jacobian : bool
        Return the Jacobians (a single state only).
    input_jacobian : bool
        With ``jacobian``: also ``G`` (False: ``G`` is None; an EKF driven
        by the measured input needs ``F`` alone).

    Returns
    -------
    x_next : (..., 5) array
    jacobians : tuple (F, G) or None
        ``F = d x_next / d x`` (5, 5) and ``G = d x_next / d u`` (5, 3), for a
        single state only.

    Notes
    -----
    The paper prints the rows in the order p_e, v_e, p_n, v_n, psi; here they
    are in state order. It prints ``psi(k) = psi(k-1) + w_z``: the step T is
    missing (a rate times no time is not an angle), so ``psi += w_z T``.
    song2016b eq. 16 prints ``e(k-1)``, ``n(k-1)`` in rows 2 and 4 where the
    velocities are meant. Yaw is not wrapped here; filters wrap it.
    """
    x = np.asarray(x, dtype=np.float64)
    ax, ay, wz = float(u[0]), float(u[1]), float(u[2])
    half_t2 = 0.5 * dt_s * dt_s
    if x.ndim == 1:  # one state: plain floats (the EKFs' hot path)
        pe, pn, ve, vn, yaw = x[:5].tolist()
        c, s = math.cos(yaw), math.sin(yaw)
        a_e, a_n = ax * c - ay * s, ax * s + ay * c
        out = x.copy()
        out[PE] = pe + (ve * dt_s + half_t2 * a_e)
        out[PN] = pn + (vn * dt_s + half_t2 * a_n)
        out[VE] = ve + a_e * dt_s
        out[VN] = vn + a_n * dt_s
        out[YAW] = yaw + wz * dt_s
    else:
        yaw = x[..., YAW]
        c, s = np.cos(yaw), np.sin(yaw)
        a_e, a_n = ax * c - ay * s, ax * s + ay * c
        out = x.copy()
        out[..., PE] += x[..., VE] * dt_s + half_t2 * a_e
        out[..., PN] += x[..., VN] * dt_s + half_t2 * a_n
        out[..., VE] += a_e * dt_s
        out[..., VN] += a_n * dt_s
        out[..., YAW] = yaw + wz * dt_s
    if not jacobian:
        return out, None
    if x.ndim != 1:
        raise ValueError("Jacobians are computed for a single state")
    F = _identity(x.shape[0])
    F[PE, VE] = F[PN, VN] = dt_s
    # d a_e / d psi = -a_n, d a_n / d psi = a_e (scalar stores: the cheapest way to fill these small arrays)
    F[PE, YAW] = -half_t2 * a_n
    F[PN, YAW] = half_t2 * a_e
    F[VE, YAW] = -dt_s * a_n
    F[VN, YAW] = dt_s * a_e
    return out, (F, _input_jacobian(x.shape[0], c, s, dt_s) if input_jacobian else None)


def improved_motion_input_jacobian(x: np.ndarray, dt_s: float) -> np.ndarray:
    """``G = d x_next / d u`` (n, 3) of :func:`improved_motion` for a single state.

    It depends on the yaw and the step only (not on the input), so a model
    that needs the accelerations' noise without eq. 16's motion (the CT
    model of song2014) takes it alone.
    """
    yaw = float(x[YAW])
    return _input_jacobian(np.shape(x)[0], math.cos(yaw), math.sin(yaw), dt_s)


def _input_jacobian(n: int, c: float, s: float, dt_s: float) -> np.ndarray:
    """``G`` of eq. 16 for a state of ``n`` entries, from ``cos psi``, ``sin psi`` and the step."""
    half_t2 = 0.5 * dt_s * dt_s
    G = np.zeros((n, 3))
    G[PE, 0], G[PE, 1] = half_t2 * c, -half_t2 * s
    G[PN, 0], G[PN, 1] = half_t2 * s, half_t2 * c
    G[VE, 0], G[VE, 1] = dt_s * c, -dt_s * s
    G[VN, 0], G[VN, 1] = dt_s * s, dt_s * c
    G[YAW, 2] = dt_s
    return G


def rotating_velocity_motion(x: np.ndarray, yaw_rate_radps: float, dt_s: float, jacobian: bool = True):
    """Fallback of eq. 16 for an IMU without accelerometers (yaw rate only).

    The velocity keeps its magnitude and turns with the measured yaw rate
    (the vehicle does not slip sideways), the position integrates it:
    ``v(k) = R(w_z T) v(k-1)``, ``p(k) = p(k-1) + v(k-1) T``,
    ``psi(k) = psi(k-1) + w_z T``. Speed changes are left to the process
    noise and corrected by the wheel-speed updates. This is the project's
    documented fallback, not a paper equation (the Plaza data has no
    accelerometers).

    Returns
    -------
    x_next : (..., 5) array
    jacobian : (5, 5) array or None
        ``d x_next / d x`` for a single state.
    """
    x = np.asarray(x, dtype=np.float64)
    dpsi = yaw_rate_radps * dt_s
    c, s = np.cos(dpsi), np.sin(dpsi)
    out = np.empty_like(x)
    out[..., PE] = x[..., PE] + x[..., VE] * dt_s
    out[..., PN] = x[..., PN] + x[..., VN] * dt_s
    out[..., VE] = c * x[..., VE] - s * x[..., VN]
    out[..., VN] = s * x[..., VE] + c * x[..., VN]
    out[..., YAW] = x[..., YAW] + dpsi
    out[..., 5:] = x[..., 5:]
    if not jacobian:
        return out, None
    F = np.eye(x.shape[-1])
    F[PE, VE] = F[PN, VN] = dt_s
    F[VE, VE], F[VE, VN], F[VN, VE], F[VN, VN] = c, -s, s, c
    return out, F


def random_walk(x: np.ndarray, dt_s: float, jacobian: bool = True):
    """song2016 eq. 10: ``X(k) = A X(k-1) + W`` with ``A = I`` (position random walk).

    Returns the state unchanged and ``F = I``; the motion lives in the
    process noise (see :func:`random_walk_noise`).
    """
    x = np.asarray(x, dtype=np.float64)
    return x.copy(), (np.eye(x.shape[-1]) if jacobian else None)


def random_walk_noise(n: int, speed_sigma_mps: float, dt_s: float) -> np.ndarray:
    """Process noise of eq. 10: a displacement of 1-sigma ``speed_sigma_mps * dt`` per axis.

    The paper gives no Q_RFID; a random walk must let the position move by
    about the vehicle's speed over a step, so Q is ``(sigma_v dt)^2 I``.
    """
    return np.eye(n) * (speed_sigma_mps * dt_s) ** 2


def constant_velocity_motion(x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity motion of ``[p_e, p_n, v_e, v_n]``: ``p += v T``, ``v`` unchanged.

    The motion prior of the ranges-only factor graph (``graph-ranges``),
    whose process noise is :func:`white_acceleration_noise`. Returns the
    next state and ``F = d x_next / d x`` (4, 4).
    """
    F = _identity(4)
    F[PE, VE] = F[PN, VN] = dt_s
    return F @ np.asarray(x, dtype=np.float64), F


def white_acceleration_noise(accel_psd_m2ps3: float, dt_s: float) -> np.ndarray:
    """Process noise of :func:`constant_velocity_motion` driven by white acceleration.

    Parameters
    ----------
    accel_psd_m2ps3 : float
        Power spectral density ``q`` of the acceleration on each axis,
        m^2/s^3 (a velocity random walk of ``sqrt(q)`` m/s per sqrt(s)).
    dt_s : float
        Step T.

    Returns
    -------
    (4, 4) array
        ``q [[T^3/3 I, T^2/2 I], [T^2/2 I, T I]]`` in ``[p_e, p_n, v_e, v_n]``
        order (the discretised white-noise-acceleration model; GTSAM's
        ``WnoaMotionFactorPoint2`` is the same prior as a factor).
    """
    t = float(dt_s)
    block = accel_psd_m2ps3 * np.array([[t**3 / 3.0, t**2 / 2.0], [t**2 / 2.0, t]])
    return np.kron(block, np.eye(2))
