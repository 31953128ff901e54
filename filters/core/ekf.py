"""Extended Kalman filter steps and chi-square gating (song2016 eq. 11-15).

Plain functions on ``(x, P)`` arrays of any size, so every EKF-like filter
of the project (RFID-EKF, Fusion-EKF, the two-level EKF, the STEKF and the
federated KF of the other papers) shares them. Models come from
:mod:`filters.models` and supply the predicted value and the Jacobians.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable, NamedTuple

import numpy as np
from scipy.stats import chi2


class Update(NamedTuple):
    """Result of a measurement update."""

    x: np.ndarray
    P: np.ndarray
    #: Normalised innovation squared ``nu^T S^-1 nu`` of the rows applied.
    nis: float


def predict(x_next: np.ndarray, F: np.ndarray, P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time update, song2016 eq. 11-12: ``x = f(x)`` (given), ``P = F P F^T + Q``.

    ``ndarray.dot`` rather than ``@``: on these tiny matrices it has half the
    call overhead (so too in :func:`update`).
    """
    return x_next, F.dot(P).dot(F.T) + Q


def update(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    z_pred: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    residual: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Update:
    """Measurement update, song2016 eq. 13-15.

    Parameters
    ----------
    x, P : (n,), (n, n)
        Prior.
    z, z_pred : (m,)
        Measurement and its prediction ``h(x)``.
    H : (m, n)
        Jacobian of ``h`` at ``x``.
    R : (m, m) or (m,)
        Measurement covariance (a vector is its diagonal).
    residual : callable, optional
        ``residual(z, z_pred)``, e.g. :func:`filters.models.angles.angle_residual`
        for a yaw measurement; plain subtraction by default.

    Notes
    -----
    The covariance is updated as ``P - K S K^T`` (eq. 15 with
    ``K = P H^T S^-1``, written so that it stays exactly symmetric). With a
    diagonal R (given as a vector) the rows are applied one at a time with
    the same linearisation (innovation ``nu_i - H_i (x_post - x)``), which
    is algebraically the joint update and needs no matrix inverse; two such
    rows (the 100 Hz wheel speed and its sideways pseudo-measurement) are
    applied jointly, with ``S^-1`` of the 2x2 ``S`` in closed form
    (:func:`_update_two_rows`: half the numpy calls of two scalar rows).
    The joint form must keep ``P`` exactly symmetric: without the
    symmetrisation, the rounding asymmetry of ``P - K (P H^T)^T`` grows
    without bound in a gyro-only dead reckoning (no accelerometers: Plaza1,
    MRCLAM), which is what once moved ``dr`` on Plaza1 from 2 m to 30 m
    RMS; with it, the joint and the row-by-row forms differ by under
    1e-10 m on Plaza1, the five MRCLAM6 robots and the simulated drives.
    """
    nu = residual(z, z_pred) if residual is not None else z - z_pred
    if not isinstance(nu, np.ndarray) or nu.ndim == 0:
        nu = np.atleast_1d(nu)
    r_ndim = R.ndim if isinstance(R, np.ndarray) else np.ndim(R)
    if r_ndim == 1 and nu.shape[0] == 2:
        return _update_two_rows(x, P, nu, H, R)
    if r_ndim == 1 or nu.shape[0] == 1:
        r = np.diag(R).tolist() if r_ndim == 2 else np.asarray(R, dtype=np.float64).ravel().tolist()
        nu_l = nu.tolist()
        x_new, P_new, nis = x, P, 0.0
        for i, h in enumerate(H):
            PHt = P_new.dot(h)
            s = float(h.dot(PHt)) + r[i]
            k = PHt / s
            nu_i = nu_l[i] if i == 0 else nu_l[i] - float(h.dot(x_new - x))
            x_new = x_new + k * nu_i
            P_new = P_new - k[:, None] * PHt  # the outer product k PHt^T
            nis += nu_i * nu_i / s
        return Update(x_new, P_new, nis)
    PHt = P @ H.T
    S = H @ PHt + R
    S_inv = np.linalg.inv(S)
    K = PHt @ S_inv
    P_new = P - K @ S @ K.T
    return Update(x + K @ nu, 0.5 * (P_new + P_new.T), float(nu @ S_inv @ nu))


def _update_two_rows(x: np.ndarray, P: np.ndarray, nu: np.ndarray, H: np.ndarray, r: np.ndarray) -> Update:
    """:func:`update` of two rows with a diagonal ``R`` (the vector ``r``), jointly.

    ``S = H P H^T + diag(r)`` is 2x2: its inverse ``[[s11, -s01], [-s10, s00]] / det``
    is written out, ``K = P H^T S^-1``, ``x + K nu``, ``P - K (P H^T)^T``
    (``= P - K S K^T``, song2016 eq. 13-15), symmetrised (see :func:`update`).
    """
    PHt = P.dot(H.T)
    (s00, s01), (s10, s11) = H.dot(PHt).tolist()
    r0, r1 = r.tolist()
    s00 += r0
    s11 += r1
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    K = PHt.dot(np.array([[i00, i01], [i10, i11]]))
    n0, n1 = nu.tolist()
    nis = n0 * (i00 * n0 + i01 * n1) + n1 * (i10 * n0 + i11 * n1)
    P_new = P - K.dot(PHt.T)
    return Update(x + K.dot(nu), 0.5 * (P_new + P_new.T), nis)


def iterated_update(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    h: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    R: np.ndarray,
    iterations: int,
) -> Update:
    """Iterated EKF measurement update (Gauss-Newton on the same posterior).

    Iteration 1 is :func:`update`; each further one relinearises ``h`` at
    the new estimate: ``x_{i+1} = x + K_i (z - h(x_i) - H_i (x - x_i))``.
    It converges to the maximum a posteriori state under the same model, Q
    and R, which matters when the prior is metres away from a tag only
    metres away (range Jacobians change fast there).

    Parameters
    ----------
    h : callable
        ``x -> (h(x), H(x))``.
    iterations : int
        1 for the plain EKF (song2016 eq. 13-15).
    """
    R = np.diag(R) if np.ndim(R) == 1 else np.atleast_2d(R)
    xi = x
    for _ in range(max(iterations, 1)):
        z_pred, H = h(xi)
        PHt = P @ H.T
        S = H @ PHt + R
        S_inv = np.linalg.inv(S)
        K = PHt @ S_inv
        nu = z - z_pred - H @ (x - xi)
        xi = x + K @ nu
    P_new = P - K @ S @ K.T
    return Update(xi, 0.5 * (P_new + P_new.T), float(nu @ S_inv @ nu))


@lru_cache(maxsize=64)
def chi2_threshold(probability: float, dof: int = 1) -> float:
    """The chi-square quantile a gate of this probability accepts below."""
    return float(chi2.ppf(probability, dof))


def gate_scalar_rows(nu: np.ndarray, S_diag: np.ndarray, probability: float) -> np.ndarray:
    """Chi-square gate for measurement rows taken one at a time.

    Parameters
    ----------
    nu : (m,) innovations
    S_diag : (m,) their predicted variances ``H_i P H_i^T + R_i``
    probability : float
        Gate probability (0.997 accepts 99.7 % of consistent rows). A value
        of 1 or more disables the gate.

    Returns
    -------
    (m,) bool : rows that pass.
    """
    if probability >= 1.0:
        return np.ones(np.shape(nu), dtype=bool)
    return nu * nu <= chi2_threshold(probability, 1) * S_diag
