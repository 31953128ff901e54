"""Measurement models with analytic Jacobians.

They index the state by the positions of :mod:`filters.models.vehicle`
(``p_e, p_n`` at 0, 1; ``v_e, v_n, psi`` at 2, 3, 4), so they serve the
2-state RFID model (ranges and fixes only), the 5-state model and any larger
state that starts with these entries. ``x`` may be one state ``(n,)`` or a
stack ``(k, n)``; Jacobians are returned for a single state only (the
wheel speed, compass and position fix also for a stack: ``(k, m, n)``,
one per state), and skipped with ``jacobian=False``.
"""

from __future__ import annotations

import math

import numpy as np

from filters.models.vehicle import PE, PN, VE, VN, YAW

#: Below this distance (m) a range Jacobian uses the floor (reader on the tag).
_MIN_RANGE_M = 1e-6


def tag_range(x: np.ndarray, tags_en_m: np.ndarray, jacobian: bool = True):
    """Ranges to tags, song2016 eq. 10/17/19 (and song2016b eq. 10).

    ``h_i = sqrt((p_e - x_i)^2 + (p_n - y_i)^2)``. The paper prints the
    noise ``n_ri`` inside the square root; it is additive outside it
    (``r_i = h_i + n_ri``), as song2016b prints it.

    Parameters
    ----------
    x : (n,) or (k, n) array
    tags_en_m : (m, 2) array
        Tag east/north.

    Returns
    -------
    ranges_m : (m,) or (k, m) array
    H : (m, n) array or None
        Rows ``[(p_e - x_i)/D_i, (p_n - y_i)/D_i, 0, ...]`` (song2016 H_RFID).
    """
    x = np.asarray(x, dtype=np.float64)
    tags = np.asarray(tags_en_m, dtype=np.float64).reshape(-1, 2)
    de = x[..., PE, None] - tags[:, 0]
    dn = x[..., PN, None] - tags[:, 1]
    r = np.sqrt(de * de + dn * dn)
    if not jacobian:
        return r, None
    if x.ndim != 1:
        raise ValueError("Jacobians are computed for a single state")
    d = np.maximum(r, _MIN_RANGE_M)
    H = np.zeros((tags.shape[0], x.shape[0]))
    H[:, PE] = de / d
    H[:, PN] = dn / d
    return r, H


def wheel_speed(x: np.ndarray, jacobian: bool = True):
    """Wheel speed along the body x axis, song2016 eq. 17/20: ``v_e cos psi + v_n sin psi``.

    Returns
    -------
    speed_mps : float or (k,) array
    H : (1, n) or (k, 1, n) array, or None
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 1:  # one state: plain floats (the EKFs' hot path)
        ve, vn, yaw = x[VE : YAW + 1].tolist()
        c, s = math.cos(yaw), math.sin(yaw)
    else:
        ve, vn, yaw = x[..., VE], x[..., VN], x[..., YAW]
        c, s = np.cos(yaw), np.sin(yaw)
    v = ve * c + vn * s
    if not jacobian:
        return v, None
    H = np.zeros(x.shape[:-1] + (1, x.shape[-1]))
    H[..., 0, VE], H[..., 0, VN], H[..., 0, YAW] = c, s, -ve * s + vn * c
    return v, H


def body_velocity(x: np.ndarray, jacobian: bool = True):
    """Velocity in the body frame: ``[forward, left]``.

    ``forward = v_e cos psi + v_n sin psi`` is the wheel speed of eq. 17;
    ``left = -v_e sin psi + v_n cos psi`` is zero for a wheel that does not
    slip sideways (the non-holonomic constraint, used as a pseudo-measurement
    with the wheel speed).

    Returns
    -------
    v_body_mps : (2,) or (k, 2) array
    H : (2, n) array or None
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 1:  # one state: plain floats (the EKFs' hot path)
        ve, vn, yaw = x[VE : YAW + 1].tolist()
        c, s = math.cos(yaw), math.sin(yaw)
        v = np.array([ve * c + vn * s, -ve * s + vn * c])
    else:
        c, s = np.cos(x[..., YAW]), np.sin(x[..., YAW])
        ve, vn = x[..., VE], x[..., VN]
        v = np.empty(x.shape[:-1] + (2,))
        v[..., 0] = ve * c + vn * s
        v[..., 1] = vn * c - ve * s
    if not jacobian:
        return v, None
    H = np.zeros((2, x.shape[-1]))
    H[0, VE], H[0, VN], H[0, YAW] = c, s, -ve * s + vn * c
    H[1, VE], H[1, VN], H[1, YAW] = -s, c, -ve * c - vn * s
    return v, H


def compass_yaw(x: np.ndarray, jacobian: bool = True):
    """Compass yaw, song2016 eq. 17/20: ``psi``. Innovations must be wrapped
    (:func:`filters.models.angles.angle_residual`).

    Returns
    -------
    yaw_rad : float or (k,) array
    H : (1, n) or (k, 1, n) array, or None
    """
    x = np.asarray(x, dtype=np.float64)
    if not jacobian:
        return x[..., YAW], None
    H = np.zeros(x.shape[:-1] + (1, x.shape[-1]))
    H[..., 0, YAW] = 1.0
    return x[..., YAW], H


def position_fix(x: np.ndarray, jacobian: bool = True):
    """A position fix (song2016b eq. 17 rows 1-2, an RSU or GNSS fix): ``[p_e, p_n]``.

    Returns
    -------
    en_m : (2,) or (k, 2) array
    H : (2, n) or (k, 2, n) array, or None
    """
    x = np.asarray(x, dtype=np.float64)
    if not jacobian:
        return x[..., :2].copy(), None
    H = np.zeros(x.shape[:-1] + (2, x.shape[-1]))
    H[..., 0, PE] = H[..., 1, PN] = 1.0
    return x[..., :2].copy(), H
