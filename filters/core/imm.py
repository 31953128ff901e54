"""Interacting multiple models, song2014 §4.3 (eq. 25-27, 40-43), as printed.

Generic over the model-matched filters: the caller steps each filter and
passes back its innovation and innovation covariance. Angle states are
mixed on the circle (their differences are wrapped).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from filters.models.angles import angle_residual, wrap_angle


def validate_markov(matrix: np.ndarray) -> np.ndarray:
    """A row-stochastic Markov matrix ``pi[j, i] = P(model i at k | model j at k-1)``."""
    pi = np.asarray(matrix, dtype=np.float64)
    if pi.ndim != 2 or pi.shape[0] != pi.shape[1] or np.any(pi < 0) or not np.allclose(pi.sum(axis=1), 1.0):
        raise ValueError(f"the Markov transition matrix must be square with rows summing to 1, got {pi.tolist()}")
    return pi


def _spread(x: np.ndarray, ref: np.ndarray, angle_states: Sequence[int]) -> np.ndarray:
    d = x - ref
    for i in angle_states:
        d[..., i] = angle_residual(x[..., i], ref[..., i])
    return d


def mix(
    states: Sequence[np.ndarray],
    covs: Sequence[np.ndarray],
    probabilities: np.ndarray,
    markov: np.ndarray,
    angle_states: Sequence[int] = (),
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Interaction, song2014 eq. (25)-(27).

    ``mu_i(k,k-1) = sum_j pi_ji mu_j``, ``mu_ji = pi_ji mu_j / mu_i(k,k-1)``,
    ``x0_i = sum_j mu_ji x_j``,
    ``P0_i = sum_j mu_ji (P_j + (x0_i - x_j)(x0_i - x_j)^T)``.

    Returns
    -------
    mixed states, mixed covariances, predicted model probabilities.
    """
    X = np.asarray(states)
    predicted = markov.T @ probabilities
    weights = markov * probabilities[:, None] / predicted[None, :]  # [j, i]
    out_x, out_P = [], []
    for i in range(len(states)):
        ref = X[0]
        x0 = ref + weights[:, i] @ _spread(X, ref, angle_states)
        for a in angle_states:
            x0[a] = wrap_angle(float(x0[a]))
        P0 = np.zeros_like(covs[0])
        for j in range(len(states)):
            d = _spread(X[j], x0, angle_states)
            P0 += weights[j, i] * (covs[j] + np.outer(d, d))
        out_x.append(x0)
        out_P.append(P0)
    return out_x, out_P, predicted


def log_likelihood(innovation: np.ndarray, innovation_cov: np.ndarray) -> float:
    """Gaussian log-likelihood of an innovation, song2014 eq. (40)."""
    if innovation.size == 0:
        return 0.0
    sign, logdet = np.linalg.slogdet(2.0 * np.pi * innovation_cov)
    return float(-0.5 * innovation @ np.linalg.solve(innovation_cov, innovation) - 0.5 * logdet)


def update_probabilities(predicted: np.ndarray, log_likelihoods: Sequence[float]) -> np.ndarray:
    """Model probability update, song2014 eq. (41) (in logs, to avoid underflow)."""
    ll = np.asarray(log_likelihoods, dtype=np.float64)
    w = np.log(predicted) + ll - np.max(ll)
    w = np.exp(w - np.max(w))
    return w / w.sum()


def combine(
    states: Sequence[np.ndarray], covs: Sequence[np.ndarray], probabilities: np.ndarray, angle_states: Sequence[int] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Combination, song2014 eq. (42)-(43)."""
    X = np.asarray(states)
    ref = X[0]
    x = ref + probabilities @ _spread(X, ref, angle_states)
    for a in angle_states:
        x[a] = wrap_angle(float(x[a]))
    P = np.zeros_like(covs[0])
    for mu, xi, Pi in zip(probabilities, X, covs):
        d = _spread(xi, x, angle_states)
        P += mu * (Pi + np.outer(d, d))
    return x, P
