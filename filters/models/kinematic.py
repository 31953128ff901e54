"""Kinematic models of song2014 (CA, CT, position-level observation) and liu2016
(the "current" statistical acceleration model and the DR observation).

Every function returns the model value together with its analytic Jacobians;
``tests/filters/test_kinematic.py`` checks each Jacobian against finite
differences.

song2014 state (§4.1), shared by the CA and CT models::

    x = [p_e, p_n, v_e, v_n, psi, omega]      (m, m, m/s, m/s, rad, rad/s)

liu2016 state (eq. 2-3)::

    x = [x_e, v_e, a_e, x_n, v_n, a_n]        (m, m/s, m/s^2, m, m/s, m/s^2)

Conventions are the project's: yaw ``psi`` from east, counter-clockwise;
``a_e = a_x cos psi - a_y sin psi``, ``a_n = a_x sin psi + a_y cos psi``;
wheel speed ``v = v_e cos psi + v_n sin psi``.
"""

from __future__ import annotations

import math

import numpy as np

from filters.models.measurements import compass_yaw, position_fix, wheel_speed
from filters.models.vehicle import PE, PN, VE, VN, _identity, improved_motion, improved_motion_input_jacobian
from filters.models.vehicle import YAW as PSI

#: Index of the yaw rate in the song2014 6-state (the first five entries are
#: song2016's 5-state, :mod:`filters.models.vehicle`).
OMEGA = 5
#: Indices of the liu2016 6-state.
XE, CVE, AE, XN, CVN, AN = range(6)

# Below this |omega T| the CT coefficients use their Taylor series (no 0/0).
_SMALL_TURN_RAD = 1e-4


# ---------------------------------------------------------------------------
# song2014 §4.1: constant acceleration (CA)
# ---------------------------------------------------------------------------


def ca_transition(x: np.ndarray, u: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CA process model, song2014 eq. (22) (lost in extraction; reconstructed).

    Body-frame accelerations ``u = [a_x, a_y]`` are rotated into east-north by
    the yaw; position and velocity integrate them over ``T``; the yaw turns
    at the state's rate ``omega``, which the CA model keeps constant::

        a_e = a_x cos psi - a_y sin psi,   a_n = a_x sin psi + a_y cos psi
        p'  = p + v T + a T^2 / 2,   v' = v + a T,
        psi' = psi + omega T,        omega' = omega

    This is song2016 eq. 16 (:func:`filters.models.vehicle.improved_motion`)
    with the yaw rate taken from the state instead of the gyro.

    Parameters
    ----------
    x : (6,) state ``[p_e, p_n, v_e, v_n, psi, omega]``
    u : (2,) ``[a_x, a_y]`` in m/s^2 (body frame, x forward, y left)
    dt_s : float
        The sampling interval ``T``.

    Returns
    -------
    x_next : (6,)
    A : (6, 6) Jacobian with respect to ``x``
    B : (6, 2) Jacobian with respect to ``u``
    """
    x_next, (A, G) = improved_motion(x, (u[0], u[1], x[OMEGA]), dt_s)
    A[PSI, OMEGA] = dt_s
    return x_next, A, G[:, :2]


def ca_input_jacobian(x: np.ndarray, dt_s: float) -> np.ndarray:
    """``B`` (6, 2) of :func:`ca_transition` alone: it depends on the yaw and ``T`` only.

    The CT model's process noise includes the accelerations' through it
    (song2014 ``B Gamma B^T``).
    """
    return improved_motion_input_jacobian(x, dt_s)[:, :2]


# ---------------------------------------------------------------------------
# song2014 §4.1: constant turn (CT)
# ---------------------------------------------------------------------------


def _turn_coefficients(w: float, T: float) -> tuple[float, float, float, float]:
    """``S = sin(wT)/w``, ``C = (1 - cos wT)/w`` and their derivatives in ``w``.

    Series expansions below ``|wT| < 1e-4`` keep them finite at ``w = 0``
    (where ``S = T``, ``C = 0``: straight-line motion).
    """
    wt = w * T
    if abs(wt) < _SMALL_TURN_RAD:
        S = T - w * w * T**3 / 6.0
        C = w * T * T / 2.0 - w**3 * T**4 / 24.0
        dS = -w * T**3 / 3.0
        dC = T * T / 2.0 - w * w * T**4 / 8.0
    else:
        sn, cs = math.sin(wt), math.cos(wt)
        S = sn / w
        C = (1.0 - cs) / w
        dS = (wt * cs - sn) / (w * w)
        dC = (wt * sn - (1.0 - cs)) / (w * w)
    return S, C, dS, dC


def ct_transition(x: np.ndarray, u: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CT process model, song2014 eq. (23) (lost in extraction; reconstructed).

    Coordinated-turn kinematics at the measured yaw rate ``w = u[0]`` (the
    paper's input ``U_2 = [w_z]``), which also becomes the state's rate::

        p_e' = p_e + (v_e sin wT - v_n (1 - cos wT)) / w
        p_n' = p_n + (v_e (1 - cos wT) + v_n sin wT) / w
        v'   = Rot(wT) v,   psi' = psi + w T,   omega' = w

    As ``w -> 0`` it tends to straight constant-velocity motion (series
    expansion, no division by zero).

    Parameters
    ----------
    x : (6,) state ``[p_e, p_n, v_e, v_n, psi, omega]``
    u : (1,) ``[w_z]`` in rad/s
    dt_s : float

    Returns
    -------
    x_next : (6,)
    A : (6, 6) Jacobian with respect to ``x``
    B : (6, 1) Jacobian with respect to ``u``
    """
    T = dt_s
    w = float(u[0])
    S, C, dS, dC = _turn_coefficients(w, T)
    cw, sw = math.cos(w * T), math.sin(w * T)
    pe, pn, ve, vn, psi = np.asarray(x, dtype=np.float64)[:5].tolist()
    x_next = np.array(
        [
            pe + S * ve - C * vn,
            pn + C * ve + S * vn,
            cw * ve - sw * vn,
            sw * ve + cw * vn,
            psi + w * T,
            w,
        ]
    )
    A = _identity(6)
    A[PE, VE], A[PE, VN] = S, -C
    A[PN, VE], A[PN, VN] = C, S
    A[VE, VE], A[VE, VN] = cw, -sw
    A[VN, VE], A[VN, VN] = sw, cw
    A[OMEGA, OMEGA] = 0.0
    B = np.zeros((6, 1))
    B[PE, 0] = dS * ve - dC * vn
    B[PN, 0] = dC * ve + dS * vn
    B[VE, 0] = T * (-sw * ve - cw * vn)
    B[VN, 0] = T * (cw * ve - sw * vn)
    B[PSI, 0] = T
    B[OMEGA, 0] = 1.0
    return x_next, A, B


# ---------------------------------------------------------------------------
# song2014 §4.2: observation [x_RFID, y_RFID, v_wheel, psi_compass]
# ---------------------------------------------------------------------------

#: Rows of the song2014 observation vector.
OBS_POSITION_E, OBS_POSITION_N, OBS_SPEED, OBS_YAW = range(4)


def position_speed_yaw_observation(x: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """song2014 eq. (24) (reconstructed): ``h(x) = [p_e, p_n, v_wheel, psi]``.

    ``v_wheel = v_e cos psi + v_n sin psi`` is the speed along the body x
    axis. Noise is additive. The rows are song2016's measurement models
    (:mod:`filters.models.measurements`) stacked.

    Parameters
    ----------
    x : (6,) song2014 state, or (k, 6) for the states of ``k`` filters
    rows : index array, optional
        Observation rows present at this epoch (e.g. ``[2, 3]`` when no RFID
        fix arrived); all four when None.

    Returns
    -------
    z_pred : (len(rows),) or (k, len(rows))
    H : (len(rows), 6) or (k, len(rows), 6) Jacobian
    """
    p, Hp = position_fix(x)
    v, Hv = wheel_speed(x)
    psi, Hpsi = compass_yaw(x)
    z = np.empty(p.shape[:-1] + (4,))
    z[..., :2] = p
    z[..., OBS_SPEED] = v
    z[..., OBS_YAW] = psi
    H = np.concatenate((Hp, Hv, Hpsi), axis=-2)
    if rows is None:
        return z, H
    return z[..., rows], H[..., rows, :]


# ---------------------------------------------------------------------------
# liu2016 eq. (1)-(5), (16): the "current" statistical acceleration model
# ---------------------------------------------------------------------------


def current_statistical_transition(dt_s: float, alpha_e_per_s: float, alpha_n_per_s: float) -> np.ndarray:
    """The 6x6 transition ``Phi = diag(Phi_e, Phi_n)`` of liu2016 eq. (4).

    ``alpha = 1 / tau`` is the reciprocal correlation time of the
    manoeuvring acceleration. (The printed continuous ``A`` of eq. (2) lacks
    the row of ``v_n``; eq. (4) is its exact discretisation.)
    """
    return _block_diag3(_cs_block(dt_s, alpha_e_per_s), _cs_block(dt_s, alpha_n_per_s))


def _cs_block(T: float, a: float) -> np.ndarray:
    e = np.exp(-a * T)
    return np.array([[1.0, T, (-1.0 + a * T + e) / a**2], [0.0, 1.0, (1.0 - e) / a], [0.0, 0.0, e]])


def _block_diag3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros((6, 6))
    out[:3, :3] = a
    out[3:, 3:] = b
    return out


def current_statistical_input(
    dt_s: float, alpha_e_per_s: float, alpha_n_per_s: float, mean_accel_e_mps2: float, mean_accel_n_mps2: float
) -> np.ndarray:
    """The input ``U(k)`` of liu2016 eq. (5) for "current" mean accelerations."""
    T = dt_s

    def block(a: float, abar: float) -> list[float]:
        g = (1.0 - np.exp(-a * T)) / a
        return [(-T + 0.5 * a * T * T + g) / a * abar, (T - g) * abar, a * g * abar]

    return np.array(block(alpha_e_per_s, mean_accel_e_mps2) + block(alpha_n_per_s, mean_accel_n_mps2))


def current_statistical_prediction(x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """liu2016 eq. (16): ``x(k/k-1) = Phi(T) x(k-1)`` with constant-acceleration blocks.

    Taking the "current" mean acceleration as the predicted one
    (``a_bar = a(k/k-1)``), eq. (4) plus eq. (5) collapse to the
    constant-acceleration transition ``[[1, T, T^2/2], [0, 1, T], [0, 0, 1]]``
    per axis, independent of ``alpha`` (``tests/filters/test_kinematic.py``
    checks the identity).

    Returns
    -------
    x_next : (6,)
    Phi : (6, 6) the (constant) Jacobian
    """
    T = dt_s
    blk = np.array([[1.0, T, 0.5 * T * T], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    Phi = _block_diag3(blk, blk)
    return Phi @ x, Phi


def current_statistical_process_noise(
    dt_s: float, sigma_accel_e_mps2: float, sigma_accel_n_mps2: float, tau_e_s: float, tau_n_s: float
) -> np.ndarray:
    """liu2016 ``Q(k-1)`` (the equation after eq. 16).

    ``Q = diag(2 sigma_ae^2 / tau_ae Q_e(T), 2 sigma_an^2 / tau_an Q_n(T))``
    with ``Q_e = Q_n = [[T^5/20, T^4/8, T^3/6], [T^4/8, T^3/3, T^2/2],
    [T^3/6, T^2/2, T]]``.
    """
    T = dt_s
    q = np.array([[T**5 / 20, T**4 / 8, T**3 / 6], [T**4 / 8, T**3 / 3, T**2 / 2], [T**3 / 6, T**2 / 2, T]])
    return _block_diag3(2.0 * sigma_accel_e_mps2**2 / tau_e_s * q, 2.0 * sigma_accel_n_mps2**2 / tau_n_s * q)


#: H of liu2016 eq. (6)-(7): east and north position of the 6-state (the
#: printed 7-column matrices are misprints).
CS_POSITION_H = np.array([[1.0, 0, 0, 0, 0, 0], [0, 0, 0, 1.0, 0, 0]])


def dr_observation(x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """liu2016 eq. (8)-(10): gyro rate and odometer distance over ``T``.

    liu2016 measures heading from north (``atan(v_e / v_n)``, clockwise), so
    its printed rate is ``(v_n a_e - v_e a_n) / |v|^2``. This project's yaw
    is from east, counter-clockwise (``psi = atan2(v_n, v_e)``), and a yaw
    gyro reports its derivative::

        omega = d/dt atan2(v_n, v_e) = (v_e a_n - v_n a_e) / (v_e^2 + v_n^2)
        s     = T sqrt(v_e^2 + v_n^2)           (calibration factor phi = 1)

    The Jacobian is derived here (the printed h1...h6 have misprints); with
    ``V = v_e^2 + v_n^2`` and ``num = v_e a_n - v_n a_e``::

        d omega/d v_e = a_n / V - 2 v_e num / V^2
        d omega/d v_n = -a_e / V - 2 v_n num / V^2
        d omega/d a_e = -v_n / V,   d omega/d a_n = v_e / V
        d s/d v_e = T v_e / |v|,    d s/d v_n = T v_n / |v|

    Both are singular at standstill; callers skip the update below a
    minimum speed.

    Returns
    -------
    z_pred : (2,) ``[omega_radps, distance_m]``
    H : (2, 6) Jacobian in the liu2016 state order
    """
    ve, vn, ae, an = x[CVE], x[CVN], x[AE], x[AN]
    V = ve * ve + vn * vn
    speed = np.sqrt(V)
    num = ve * an - vn * ae
    z = np.array([num / V, dt_s * speed])
    H = np.zeros((2, 6))
    H[0, CVE] = an / V - 2.0 * ve * num / V**2
    H[0, CVN] = -ae / V - 2.0 * vn * num / V**2
    H[0, AE] = -vn / V
    H[0, AN] = ve / V
    H[1, CVE] = dt_s * ve / speed
    H[1, CVN] = dt_s * vn / speed
    return z, H
