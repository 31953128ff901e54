"""Federated filtering: information sharing and master fusion (song2016 §5.4).

Generic over the state size; angle states are fused on the circle. Used by
the FUKF (song2016) and reusable by any federated design (liu2016).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from filters.models.angles import angle_residual, wrap_angle


def share_information(P_g: np.ndarray, Q: np.ndarray, beta: Sequence[float]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Information sharing, song2016 eq. 34-35.

    ``P_j = P_g / beta_j``, ``Q_j = Q / beta_j`` for each filter with
    ``beta_j > 0`` (eq. 35: the ``beta`` sum to one, including the master's
    ``beta_m``, which is 0 in song2016 — then the master keeps no state).

    Returns
    -------
    list of (P_j, Q_j), one per beta (None for a zero beta).
    """
    beta = np.asarray(beta, dtype=np.float64)
    if np.any(beta < 0) or not np.isclose(beta.sum(), 1.0):
        raise ValueError(f"information-sharing coefficients must be >= 0 and sum to 1, got {beta.tolist()}")
    return [(P_g / b, Q / b) if b > 0 else None for b in beta]


def fuse(
    estimates: Sequence[tuple[np.ndarray, np.ndarray]], angle_states: Sequence[int] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Master fusion, song2016 eq. 36-37.

    ``P_g = (sum P_j^-1)^-1``, ``x_g = P_g sum P_j^-1 x_j``. Angles are
    fused as residuals about the first estimate (so ``+pi`` and ``-pi``
    average to ``pi``, not 0), then wrapped.

    Parameters
    ----------
    estimates : sequence of (x_j, P_j)
    angle_states : sequence of int
    """
    ref = np.asarray(estimates[0][0], dtype=np.float64)
    info = np.zeros((ref.size, ref.size))
    info_vec = np.zeros(ref.size)
    for x, P in estimates:
        d = np.asarray(x, dtype=np.float64) - ref
        for i in angle_states:
            d[i] = angle_residual(float(x[i]), float(ref[i]))
        Y = np.linalg.inv(P)
        info += Y
        info_vec += Y @ d
    P_g = np.linalg.inv(info)
    x_g = ref + P_g @ info_vec
    for i in angle_states:
        x_g[i] = wrap_angle(float(x_g[i]))
    return x_g, 0.5 * (P_g + P_g.T)
