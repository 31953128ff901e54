"""Interacting multiple models, song2014 §4.3 (eq. 25-27, 40-43), as printed.

Generic over the model-matched filters: the caller steps each filter and
passes back its innovation and innovation covariance. Angle states are
mixed on the circle (their differences are wrapped).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from filters.models.angles import wrap_angle


def validate_markov(matrix: np.ndarray) -> np.ndarray:
    """A row-stochastic Markov matrix ``pi[j, i] = P(model i at k | model j at k-1)``."""
    pi = np.asarray(matrix, dtype=np.float64)
    if pi.ndim != 2 or pi.shape[0] != pi.shape[1] or np.any(pi < 0) or not np.allclose(pi.sum(axis=1), 1.0):
        raise ValueError(f"the Markov transition matrix must be square with rows summing to 1, got {pi.tolist()}")
    return pi


def _spread(x: np.ndarray, ref: np.ndarray, angle_states: Sequence[int]) -> np.ndarray:
    """``x - ref`` with angle entries wrapped (broadcasting)."""
    d = x - ref
    for i in angle_states:
        d[..., i] = wrap_angle(d[..., i])
    return d


def _weighted_moments(
    X: np.ndarray, P: np.ndarray, weights: np.ndarray, angle_states: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """For each column ``i`` of ``weights`` (j, i): ``x_i = sum_j w_ji x_j`` and
    ``P_i = sum_j w_ji (P_j + (x_j - x_i)(x_j - x_i)^T)``, angles on the circle."""
    ref = X[0]
    x = ref + weights.T @ _spread(X, ref, angle_states)  # (i, n)
    for i in angle_states:
        x[:, i] = wrap_angle(x[:, i])
    d = _spread(X[:, None, :], x[None, :, :], angle_states)  # (j, i, n)
    # sum_j w_ji d_ji d_ji^T and sum_j w_ji P_j as matrix products (cheaper than einsum on these sizes)
    spread = (weights[:, :, None] * d).transpose(1, 2, 0) @ d.transpose(1, 0, 2)
    k, n = P.shape[0], P.shape[1]
    return x, (weights.T @ P.reshape(k, n * n)).reshape(-1, n, n) + spread


def mix(
    states: np.ndarray,
    covs: np.ndarray,
    probabilities: np.ndarray,
    markov: np.ndarray,
    angle_states: Sequence[int] = (),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interaction, song2014 eq. (25)-(27), for stacked model states (k, n), (k, n, n).

    ``mu_i(k,k-1) = sum_j pi_ji mu_j``, ``mu_ji = pi_ji mu_j / mu_i(k,k-1)``,
    ``x0_i = sum_j mu_ji x_j``,
    ``P0_i = sum_j mu_ji (P_j + (x0_i - x_j)(x0_i - x_j)^T)``.

    Returns
    -------
    mixed states (k, n), mixed covariances (k, n, n), predicted model probabilities (k,).
    """
    predicted = markov.T @ probabilities
    weights = markov * probabilities[:, None] / predicted[None, :]  # [j, i]
    x0, P0 = _weighted_moments(np.asarray(states), np.asarray(covs), weights, list(angle_states))
    return x0, P0, predicted


def log_likelihood(
    innovation: np.ndarray, innovation_cov: np.ndarray, whitened: np.ndarray | None = None, logdet: np.ndarray | None = None
) -> np.ndarray:
    """Gaussian log-likelihoods of stacked innovations (k, r) with covariances
    (k, r, r), song2014 eq. (40).

    ``whitened`` (``S^-1 g``, (k, r)) and ``logdet`` (``log det S``, (k,))
    are taken when the caller has them already (the STEKF step has them
    from the solve for its gain, :class:`filters.core.stekf.Step`).
    """
    r = innovation.shape[-1]
    if r == 0:
        return np.zeros(innovation.shape[0])
    if logdet is None:
        logdet = np.linalg.slogdet(innovation_cov)[1]
    if whitened is None:
        whitened = np.linalg.solve(innovation_cov, innovation[..., None])[..., 0]
    maha = np.einsum("ki,ki->k", innovation, whitened)
    return -0.5 * (maha + logdet + r * math.log(2.0 * math.pi))


def update_probabilities(predicted: np.ndarray, log_likelihoods: np.ndarray) -> np.ndarray:
    """Model probability update, song2014 eq. (41) (in logs, to avoid underflow)."""
    # a few models: plain floats cost less than numpy calls
    w = [math.log(p) + ll for p, ll in zip(np.asarray(predicted).tolist(), np.asarray(log_likelihoods, dtype=np.float64).tolist())]
    w_max = max(w)
    e = [math.exp(v - w_max) for v in w]
    total = sum(e)
    return np.array([v / total for v in e])


def combine(
    states: np.ndarray, covs: np.ndarray, probabilities: np.ndarray, angle_states: Sequence[int] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Combination, song2014 eq. (42)-(43), for stacked model states."""
    x, P = _weighted_moments(np.asarray(states), np.asarray(covs), np.asarray(probabilities)[:, None], list(angle_states))
    return x[0], P[0]
