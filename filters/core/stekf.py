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

With fading disabled (``lambda = 1``) a step is
:func:`filters.core.ekf.predict` followed by :func:`filters.core.ekf.update`.
:func:`step` works on a stack of filters (an IMM's model-matched STEKFs in
one pass; a single filter is a stack of one).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from filters.core.linalg import solve_spd_logdet
from filters.models.angles import wrap_angle
from graphpos.errors import ConfigError


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

    def __post_init__(self) -> None:
        if not 0.0 < self.forgetting_factor <= 1.0:
            raise ConfigError(f"forgetting_factor must lie in (0, 1], got {self.forgetting_factor}")
        if not self.softening_factor >= 1.0:
            raise ConfigError(f"softening_factor must be >= 1, got {self.softening_factor}")


class FadingMemory:
    """The innovation second-moment estimates ``S(k)`` of ``k`` filters.

    Kept over the full observation vector; an epoch that observes only some
    rows updates only their block (rows seen for the first time start at
    ``g g^T``, the ``k = 0`` case). Only the diagonals are stored
    (``S_diag``, (k, m)): ``lambda`` reads ``S`` through ``tr N`` alone, and
    each diagonal entry follows the recursion by itself,
    ``S_ii(k) = (rho S_ii(k-1) + g_i^2) / (1 + rho)``.
    """

    def __init__(self, obs_size: int, filters: int = 1):
        self.S_diag = np.zeros((filters, obs_size))
        self.seen = np.zeros(obs_size, dtype=bool)

    def factor(
        self,
        rows: np.ndarray,
        g: np.ndarray,
        HA: np.ndarray,
        P: np.ndarray,
        HQH: np.ndarray,
        R: np.ndarray,
        config: FadingConfig,
    ) -> np.ndarray:
        """Update ``S`` with the innovations ``g`` (k, r) of ``rows`` and
        return ``lambda`` (k,); ``HA = H A`` (k, r, n), ``HQH = H Q H^T``."""
        g2 = g * g  # the diagonal of g g^T
        rho = config.forgetting_factor
        first, last = int(rows[0]), int(rows[-1])
        if last - first + 1 == len(rows):  # consecutive rows (nearly every epoch): a view, cheaper than fancy indexing
            rows = slice(first, last + 1)
        S = (rho * self.S_diag[:, rows] + g2) / (1.0 + rho) if self.seen[rows].all() else g2
        self.S_diag[:, rows] = S
        self.seen[rows] = True
        tr_n = (S - HQH.diagonal(axis1=1, axis2=2)).sum(axis=1) - config.softening_factor * R.trace()
        tr_m = np.einsum("kij,kjl,kil->k", HA, P, HA)  # tr(H A P A^T H^T)
        # lambda = max(1, tr N / tr M), 1 where tr M is not positive (a few filters: plain floats)
        return np.array([max(n / m, 1.0) if m > 0 else 1.0 for n, m in zip(tr_n.tolist(), tr_m.tolist())])


class Step(NamedTuple):
    """One STEKF step of ``k`` filters (leading axis)."""

    x: np.ndarray
    P: np.ndarray
    #: Innovations ``g = z - h(x(k, k-1))`` and their covariances
    #: ``H P(k,k-1) H^T + R`` (the IMM likelihood, song2014 eq. 40).
    innovation: np.ndarray
    innovation_cov: np.ndarray
    fading: np.ndarray
    #: ``S^-1 g`` of each filter and ``log det S``, from the same Cholesky
    #: solve as the gain (the IMM likelihood's terms, song2014 eq. 40).
    whitened_innovation: np.ndarray
    innovation_logdet: np.ndarray


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
    angle_rows: np.ndarray | None = None,
) -> Step:
    """Predict with fading and update (song2014 eq. 28-39), for ``k`` filters at once.

    Parameters
    ----------
    x_pred : (k, n)
        ``f(x(k-1), u(k))`` of each filter.
    A, P, Q : (k, n, n)
        Process Jacobians, covariances at ``k-1``, noise added after ``A P A^T``.
    z : (r,)
        The observation rows present at this step; ``z_pred`` (k, r) and
        ``H`` (k, r, n) their predictions and Jacobians; ``R`` (r, r).
    rows : index array
        Which rows of the full observation vector they are (fading memory).
    angle_rows : index array, optional
        Positions in ``z`` of angles, whose innovations are wrapped.

    Notes
    -----
    The update is the EKF's (``K = P H^T S^-1``, ``P = P - K S K^T``, as in
    :func:`filters.core.ekf.update`), written over the stacked filters so an
    IMM steps its model-matched filters in one pass; with fading disabled a
    step equals :func:`filters.core.ekf.predict` + :func:`filters.core.ekf.update`
    (``tests/filters/test_song2014.py``).
    """
    g = z[None, :] - z_pred
    for i in () if angle_rows is None else angle_rows:
        g[:, i] = wrap_angle(g[:, i])
    APA = A @ P @ A.transpose(0, 2, 1)
    Ht = H.transpose(0, 2, 1)
    if config.enabled:
        HA = H @ A
        HQH = H @ Q @ Ht
        lam = memory.factor(rows, g, HA, P, HQH, R, config)
    else:
        lam = np.ones(x_pred.shape[0])
    P_pred = lam[:, None, None] * APA + Q
    PHt = P_pred @ Ht
    HPt = PHt.transpose(0, 2, 1)
    S = H @ PHt + R
    # one solve per filter for the gain K = P H^T S^-1 (S symmetric) and S^-1 g
    rhs = np.concatenate((HPt, g[:, :, None]), axis=2)
    solved, logdet = np.empty_like(rhs), np.empty(len(S))
    for i, (S_i, rhs_i) in enumerate(zip(S, rhs)):
        solved[i], logdet[i] = solve_spd_logdet(S_i, rhs_i)
    K = solved[:, :, :-1].transpose(0, 2, 1)
    whitened = solved[:, :, -1]
    x = x_pred + (PHt @ solved[:, :, -1:])[:, :, 0]  # K g
    P_new = P_pred - K @ HPt  # K S K^T = K (P H^T)^T
    return Step(x, 0.5 * (P_new + P_new.transpose(0, 2, 1)), g, S, lam, whitened, logdet)
