"""Unscented Kalman filter with the scaled unscented transform.

The song2016 UKF equations (21)-(33) are garbled in print; this is the
standard scaled unscented transform of Wan & van der Merwe (2000), the form
filterpy's ``MerweScaledSigmaPoints`` / ``UnscentedKalmanFilter`` implement
(the tests check step-by-step agreement), with

* ``P_xz = sum Wc (chi - x)(Z - z)^T`` (eq. 30 as printed multiplies two sums);
* ``P = P_prior - K P_zz K^T`` (eq. 33 prints ``+``, a misprint);
* angle components (yaw) averaged on the circle and their residuals wrapped.

Products are ``ndarray.dot`` (cheaper than ``@`` on these small matrices).

The update draws its sigma points from the current mean and covariance
(the prior including Q), as filterpy does, so consecutive updates at one
time (wheel speed and compass) are handled alike.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from filters.core.ekf import gate_scalar_rows
from filters.core.linalg import cholesky_lower, solve_spd
from filters.models.angles import circular_mean, wrap_angle


class MerweScaledSigmaPoints:
    """Scaled sigma points (Wan & van der Merwe), ``2n+1`` of them.

    ``lambda = alpha^2 (n + kappa) - n``; ``chi_0 = x``,
    ``chi_i = x +- (sqrt((n + lambda) P))_i`` with the columns of the lower
    Cholesky factor; ``Wm_0 = lambda / (n + lambda)``,
    ``Wc_0 = Wm_0 + 1 - alpha^2 + beta``, ``W_i = 1 / (2 (n + lambda))``.

    Parameters
    ----------
    n : int
        State size.
    alpha, beta, kappa : float
        Spread, prior-knowledge (2 for Gaussians) and secondary scaling.
    """

    def __init__(self, n: int, alpha: float = 0.5, beta: float = 2.0, kappa: float = 0.0):
        self.n = n
        self.alpha, self.beta, self.kappa = alpha, beta, kappa
        lam = alpha * alpha * (n + kappa) - n
        self.scale = n + lam
        self.Wm = np.full(2 * n + 1, 0.5 / self.scale)
        self.Wc = self.Wm.copy()
        self.Wm[0] = lam / self.scale
        self.Wc[0] = lam / self.scale + 1.0 - alpha * alpha + beta

    def sigma_points(self, x: np.ndarray, P: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(2n+1, n) sigma points of ``N(x, P)`` (written into ``out`` when given).

        A ``P`` that has lost positive definiteness is first projected onto
        the nearest positive-definite matrix (:func:`nearest_positive_definite`).
        Deviation from the textbook filter, which assumes it never happens:
        the scaled transform's negative centre weight (``Wc_0 < 0`` with
        alpha 0.3) can make an updated covariance indefinite when the
        heading is uncertain by tens of degrees, and the FUKF then stopped
        with a traceback (MRCLAM6 robot 3 from a start pose with a 30 deg
        yaw sigma).
        """
        L = cholesky_lower(self.scale * P)
        if L is None:
            L = np.linalg.cholesky(self.scale * nearest_positive_definite(P))
        if out is None:
            out = np.empty((2 * self.n + 1, self.n))
        out[0] = x
        np.add(x, L.T, out=out[1 : self.n + 1])
        np.subtract(x, L.T, out=out[self.n + 1 :])
        return out


def nearest_positive_definite(P: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """The symmetric part of ``P`` with its eigenvalues raised to at least ``floor`` times the largest (and > 0).

    The nearest positive-definite matrix in the Frobenius norm (Higham 1988)
    up to the floor, which keeps a Cholesky factor computable.
    """
    S = 0.5 * (P + P.T)
    w, V = np.linalg.eigh(S)
    w = np.maximum(w, floor * max(float(w.max()), 1.0))
    return (V * w).dot(V.T)


def _mean(points: np.ndarray, Wm: np.ndarray, angles: Sequence[int]) -> np.ndarray:
    m = Wm.dot(points)
    for i in angles:
        m[i] = circular_mean(points[:, i], Wm)
    return m


def _deviations(points: np.ndarray, mean: np.ndarray, angles: Sequence[int]) -> np.ndarray:
    d = points - mean
    for i in angles:
        d[:, i] = wrap_angle(d[:, i])
    return d


def _inverse(S: np.ndarray) -> np.ndarray:
    """Inverse of a 1x1 or 2x2 SPD matrix, in closed form."""
    if S.shape[0] == 1:
        return 1.0 / S
    a, b, c, d = S[0, 0], S[0, 1], S[1, 0], S[1, 1]
    return np.array([[d, -b], [-c, a]]) / (a * d - b * c)


class UnscentedKalmanFilter:
    """An additive-noise UKF on a state of any size.

    Parameters
    ----------
    x0, P0 : initial mean and covariance.
    points : MerweScaledSigmaPoints
        The sigma-point strategy.
    angle_states : sequence of int
        State indices that are angles (averaged on the circle, wrapped).
    """

    def __init__(self, x0: np.ndarray, P0: np.ndarray, points: MerweScaledSigmaPoints, angle_states: Sequence[int] = ()):
        self.x = np.array(x0, dtype=np.float64)
        self.P = np.array(P0, dtype=np.float64)
        self.points = points
        self.angle_states = tuple(angle_states)

    def reset(self, x: np.ndarray, P: np.ndarray) -> None:
        """Replace the estimate (federated reset)."""
        self.x = np.array(x, dtype=np.float64)
        self.P = np.array(P, dtype=np.float64)

    def predict(self, fx: Callable[[np.ndarray], np.ndarray], Q: np.ndarray) -> None:
        """Time update: propagate the sigma points through ``fx`` (vectorised over rows)."""
        self.predict_points(fx(self.points.sigma_points(self.x, self.P)), Q)

    def predict_points(self, points: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Time update from sigma points of the current estimate, already propagated.

        Parameters
        ----------
        points : (2n+1, n)
            ``self.points.sigma_points(self.x, self.P)`` after the process model.
        Q : (n, n)
            Process noise, added to the propagated spread.

        Returns
        -------
        (2n+1, n)
            The points' deviations from the new mean (angles wrapped): the
            ``dx`` of :meth:`update_points` when the same points also give a
            measurement prediction.
        """
        x = _mean(points, self.points.Wm, self.angle_states)
        d = _deviations(points, x, self.angle_states)
        self.P = d.T.dot(self.points.Wc[:, None] * d) + Q
        for i in self.angle_states:
            x[i] = wrap_angle(float(x[i]))
        self.x = x
        return d

    def update(self, z: np.ndarray, hx: Callable[[np.ndarray], np.ndarray], R: np.ndarray,
               angle_measurements: Sequence[int] = (), gate_probability: float = 1.0) -> tuple[float, np.ndarray]:
        """Measurement update with sigma points drawn from the current estimate.

        Parameters
        ----------
        z : (m,) measurement
        hx : callable
            ``(k, n) -> (k, m)`` measurement function over sigma points.
        R, angle_measurements, gate_probability
            As in :meth:`update_points`.

        Returns
        -------
        nis : float
        accepted : (m,) bool
            As in :meth:`update_points`.
        """
        sig = self.points.sigma_points(self.x, self.P)
        Z = hx(sig).reshape(sig.shape[0], -1)
        dx = _deviations(sig, self.x, self.angle_states)
        return self.update_points(z, Z, dx, R, angle_measurements, gate_probability)

    def update_points(
        self,
        z: np.ndarray,
        Z: np.ndarray,
        dx: np.ndarray,
        R: np.ndarray,
        angle_measurements: Sequence[int] = (),
        gate_probability: float = 1.0,
    ) -> tuple[float, np.ndarray]:
        """Measurement update from a measurement predicted on given sigma points.

        Parameters
        ----------
        z : (m,) measurement
        Z : (2n+1, m)
            The measurement function on each sigma point.
        dx : (2n+1, n)
            Those sigma points' state deviations from ``self.x`` (they give
            ``P_xz = sum Wc dx dz^T``).
        R : (m,) or (m, m)
            Measurement covariance (a vector is its diagonal).
        angle_measurements : sequence of int
            Measurement indices that are angles.
        gate_probability : float
            Per-row chi-square gate on ``nu_i^2 / P_zz,ii``; 1 disables it.
            Gated rows are dropped before the update.

        Returns
        -------
        nis : float
            Normalised innovation squared of the applied rows (0 if none).
        accepted : (m,) bool
        """
        Wm, Wc = self.points.Wm, self.points.Wc
        z = np.atleast_1d(np.asarray(z, dtype=np.float64))
        z_mean = _mean(Z, Wm, angle_measurements)
        dz = _deviations(Z, z_mean, angle_measurements)
        Pzz = dz.T.dot(Wc[:, None] * dz)
        if np.ndim(R) == 1:
            Pzz.flat[:: Pzz.shape[0] + 1] += R
        else:
            Pzz += R
        nu = z - z_mean
        for i in angle_measurements:
            nu[i] = wrap_angle(float(nu[i]))
        if gate_probability < 1.0:
            accepted = gate_scalar_rows(nu, Pzz.diagonal().copy(), gate_probability)
            if not accepted.any():
                return 0.0, accepted
            if not accepted.all():
                dz, nu = dz[:, accepted], nu[accepted]
                Pzz = Pzz[np.ix_(accepted, accepted)]
        else:
            accepted = np.ones(nu.shape[0], dtype=bool)
        Pxz = dx.T.dot(Wc[:, None] * dz)
        # K = Pxz Pzz^-1 and Pzz^-1 nu: closed forms for one or two rows, else one Cholesky solve for both
        if nu.shape[0] <= 2:
            Pzz_inv = _inverse(Pzz)
            K, whitened = Pxz.dot(Pzz_inv), Pzz_inv.dot(nu)
        else:
            solved = solve_spd(Pzz, np.column_stack((Pxz.T, nu)))
            K, whitened = solved[:, :-1].T, solved[:, -1]
        x = self.x + K.dot(nu)
        for i in self.angle_states:
            x[i] = wrap_angle(float(x[i]))
        P = self.P - K.dot(Pxz.T)  # K Pzz K^T = K Pxz^T
        self.x, self.P = x, 0.5 * (P + P.T)
        return float(nu.dot(whitened)), accepted
