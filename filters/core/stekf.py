"""Strong-tracking EKF: the suboptimal fading factor of song2014 §4.3 step (2).

The STEKF is the EKF of :mod:`filters.core.ekf` with the predicted
covariance inflated by a fading factor ``lambda >= 1`` when the innovations
grow beyond what the filter expects (song2014 eq. 33-39)::

    S(k) = g(0) g(0)^T                               k = 0
    S(k) = (rho S(k-1) + g(k) g(k)^T) / (1 + rho)    k >= 1
    N(k) = S(k) - H Q H^T - beta R
    M(k) = H A P A^T H^T
    lambda = max(1, tr N / tr M)
    P(k, k-1) = lambda A P A^T + Q

``rho`` is the forgetting factor, ``beta >= 1`` the softening factor. The
paper prints ``H(k-1)``, ``A(k-1)``, ``P(k-1)`` in ``N`` and ``M``; this is
the standard one-step form (Zhou and Frank's strong tracking filter), where
the Jacobians are those of the step being taken. The paper's fading *matrix*
``diag(lambda_i1, ...)`` is used with equal entries (its approximate
calculation, eq. 36-37, gives one ``lambda_0i`` per filter). ``Q`` here is
everything added after ``A P A^T`` (input noise ``B Gamma B^T`` plus process
noise), which the fading factor does not scale.

With fading disabled (``lambda = 1``) a step is exactly
:func:`filters.core.ekf.predict` followed by :func:`filters.core.ekf.update`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from filters.core import ekf


@dataclass(frozen=True)
class FadingConfig:
    """song2014 §4.3 strong-tracking parameters.

    Attributes
    ----------
    enabled : bool
        False: ``lambda = 1`` (a plain EKF).
    forgetting_factor : float
        ``rho`` in (0, 1]: weight of past innovations in ``S``.
    softening_factor : float
        ``beta >= 1``: larger values make the filter fade less readily.
    """

    enabled: bool = True
    forgetting_factor: float = 0.95
    softening_factor: float = 1.0


class FadingMemory:
    """The innovation second-moment estimate ``S(k)`` of one filter.

    Kept over the full observation vector; an epoch that observes only some
    rows updates only their block (rows seen for the first time start at
    ``g g^T``, the ``k = 0`` case).
    """

    def __init__(self, obs_size: int):
        self.S = np.zeros((obs_size, obs_size))
        self.seen = np.zeros(obs_size, dtype=bool)

    def copy(self) -> "FadingMemory":
        out = FadingMemory(self.S.shape[0])
        out.S, out.seen = self.S.copy(), self.seen.copy()
        return out

    def factor(
        self,
        rows: np.ndarray,
        g: np.ndarray,
        H: np.ndarray,
        A: np.ndarray,
        P: np.ndarray,
        Q: np.ndarray,
        R: np.ndarray,
        config: FadingConfig,
    ) -> float:
        """Update ``S`` with the innovation ``g`` of ``rows`` and return ``lambda``."""
        block = np.ix_(rows, rows)
        ggT = np.outer(g, g)
        rho = config.forgetting_factor
        if self.seen[rows].all():
            S = (rho * self.S[block] + ggT) / (1.0 + rho)
        else:
            S = ggT
        self.S[block] = S
        self.seen[rows] = True
        HA = H @ A
        N = S - H @ Q @ H.T - config.softening_factor * R
        M = HA @ P @ HA.T
        tr_m = np.trace(M)
        if tr_m <= 0:
            return 1.0
        return max(1.0, float(np.trace(N) / tr_m))


class Step(NamedTuple):
    """One STEKF step."""

    x: np.ndarray
    P: np.ndarray
    #: Innovation ``g = z - h(x(k, k-1))`` and its covariance ``H P(k,k-1) H^T + R``
    #: (the IMM likelihood, song2014 eq. 40).
    innovation: np.ndarray
    innovation_cov: np.ndarray
    fading: float


def step(
    x_pred: np.ndarray,
    A: np.ndarray,
    P: np.ndarray,
    Q: np.ndarray,
    z: np.ndarray,
    z_pred: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    rows: np.ndarray,
    memory: FadingMemory,
    config: FadingConfig,
    residual: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Step:
    """Predict with fading and update (song2014 eq. 28-39).

    Parameters
    ----------
    x_pred : (n,)
        ``f(x(k-1), u(k))``.
    A : (n, n)
        Process Jacobian. ``P`` is the covariance at ``k-1``; ``Q`` the noise
        added after ``A P A^T``.
    z, z_pred, H, R :
        Observation rows present at this step (``R`` a vector: its diagonal).
    rows : index array
        Which rows of the full observation vector they are (fading memory).
    residual : callable, optional
        ``residual(z, z_pred)`` (wrap yaw rows).
    """
    R = np.diag(R) if np.ndim(R) == 1 else np.atleast_2d(R)
    g = residual(z, z_pred) if residual is not None else z - z_pred
    lam = memory.factor(rows, g, H, A, P, Q, R, config) if config.enabled else 1.0
    _, P_pred = ekf.predict(x_pred, A, lam * P, Q)
    upd = ekf.update(x_pred, P_pred, z, z_pred, H, R, residual)
    return Step(upd.x, upd.P, g, H @ P_pred @ H.T + R, lam)
