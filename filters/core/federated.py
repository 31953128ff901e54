"""Federated filtering: information sharing and master fusion (song2016 §5.4).

Generic over the state size; angle states are fused on the circle. Used by
the FUKF (song2016) and reusable by any federated design (liu2016).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from filters.core.linalg import solve_spd
from filters.models.angles import wrap_angle


def share_information(P_g: np.ndarray, Q: np.ndarray, beta: Sequence[float]) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Information sharing, song2016 eq. 34-35.

    ``P_j = P_g / beta_j``, ``Q_j = Q / beta_j`` for each filter with
    ``beta_j > 0`` (eq. 35: the ``beta`` sum to one, including the master's
    ``beta_m``, which is 0 in song2016 — then the master keeps no state).

    Returns
    -------
    list of (P_j, Q_j), one per beta (None for a zero beta).
    """
    beta = [float(b) for b in beta]
    if min(beta) < 0 or not math.isclose(sum(beta), 1.0, rel_tol=1e-9, abs_tol=1e-9):
        raise ValueError(f"information-sharing coefficients must be >= 0 and sum to 1, got {beta}")
    return [(P_g / b, Q / b) if b > 0 else None for b in beta]


def fuse(
    estimates: Sequence[tuple[np.ndarray, np.ndarray]], angle_states: Sequence[int] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Master fusion, song2016 eq. 36-37.

    ``P_g = (sum P_j^-1)^-1``, ``x_g = P_g sum P_j^-1 x_j``, computed by
    folding the estimates in one at a time with the equivalent two-estimate
    form ``K = P_a (P_a + P_b)^-1``, ``x_ab = x_a + K (x_b - x_a)``,
    ``P_ab = P_a - K P_a``: one linear solve per estimate instead of an
    inverse of every ``P_j`` and of their information sum (cheaper, and no
    inverse of a single, possibly ill-conditioned ``P_j``). Angle differences
    are wrapped (so ``+pi`` and ``-pi`` average to ``pi``, not 0), and the
    fused angles too.

    Parameters
    ----------
    estimates : sequence of (x_j, P_j)
    angle_states : sequence of int
    """
    x_g = np.array(estimates[0][0], dtype=np.float64)
    P_g = np.array(estimates[0][1], dtype=np.float64)
    for x, P in estimates[1:]:
        d = np.asarray(x, dtype=np.float64) - x_g
        for i in angle_states:
            d[i] = wrap_angle(float(d[i]))
        K = solve_spd(P_g + P, P_g).T  # P_g (P_g + P)^-1, both symmetric
        x_g = x_g + K.dot(d)
        P_g = P_g - K.dot(P_g)
    for i in angle_states:
        x_g[i] = wrap_angle(float(x_g[i]))
    return x_g, 0.5 * (P_g + P_g.T)
