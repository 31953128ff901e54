"""LSSVM regression (song2016 eq. 1-9): the KKT system, function recovery, cross-validation."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.errors import ConfigError
from graphpos.ranging.lssvm import LssvmRangeModel, fold_predictions, rbf_kernel, solve_lssvm


def _eq6_reference(x, y, gamma, kernel_sigma):
    """The bordered matrix and right-hand side of song2016 eq. 6, built independently."""
    n = x.size
    omega = np.array([[np.exp(-((xi - xj) ** 2) / (2 * kernel_sigma**2)) for xj in x] for xi in x])  # eq. 7-8
    a = np.zeros((n + 1, n + 1))
    a[0, 1:] = 1.0
    a[1:, 0] = 1.0
    a[1:, 1:] = omega + np.eye(n) / gamma
    return a, np.concatenate(([0.0], y)), omega


def test_solution_satisfies_kkt_system():
    rng = np.random.default_rng(1)
    x = np.sort(rng.uniform(100, 250, 60))
    y = rng.uniform(0, 9, 60)
    gamma, kernel_sigma = 10.0, 15.0
    b, alpha = solve_lssvm(x, y, gamma, kernel_sigma)
    a, rhs, omega = _eq6_reference(x, y, gamma, kernel_sigma)
    z = np.concatenate(([b], alpha))
    residual = np.abs(a @ z - rhs).max() / (np.abs(a).sum(axis=1).max() * np.abs(z).max())
    assert residual < 1e-14
    # eq. 5: sum alpha = 0 and alpha_k = gamma e_k with e_k = y_k - f(x_k), f by eq. 9
    assert abs(alpha.sum()) < 1e-10 * np.abs(alpha).max()
    e = y - (omega @ alpha + b)
    np.testing.assert_allclose(alpha, gamma * e, rtol=1e-9, atol=1e-10 * np.abs(alpha).max())


def test_cross_validation_solutions_equal_the_direct_solve():
    rng = np.random.default_rng(9)
    x, y = rng.uniform(100, 250, 80), rng.uniform(0, 9, 80)
    x_test = rng.uniform(100, 250, 30)
    gammas = np.array([0.1, 10.0, 1e4])
    fast = fold_predictions(x, y, x_test, 20.0, gammas)
    for g, gamma in enumerate(gammas):
        b, alpha = solve_lssvm(x, y, gamma, 20.0)
        np.testing.assert_allclose(fast[g], rbf_kernel(x_test, x, 20.0) @ alpha + b, atol=1e-6)


def _truth(x):
    return np.sin(x) + 0.1 * x**2


def test_recovers_known_nonlinear_function():
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 10, 300)
    model = LssvmRangeModel(seed=3).fit(x, _truth(x) + 0.05 * rng.standard_normal(x.size))
    grid = np.linspace(0.2, 9.8, 200)
    assert np.abs(model.predict_distance_m(grid) - _truth(grid)).max() < 0.1


def test_cross_validation_beats_poor_hyper_parameters():
    rng = np.random.default_rng(4)
    x = rng.uniform(0, 10, 200)
    y = _truth(x) + 0.2 * rng.standard_normal(x.size)
    x_test = rng.uniform(0, 10, 500)
    y_test = _truth(x_test) + 0.2 * rng.standard_normal(x_test.size)

    def test_mse(model):
        return np.mean((model.fit(x, y).predict_distance_m(x_test) - y_test) ** 2)

    searching = LssvmRangeModel(seed=5)
    cv = test_mse(searching)
    # a second fit searches again: on inputs ten times wider it picks a ten times wider kernel
    assert searching.fit(10 * x, y).kernel_sigma == pytest.approx(10 * LssvmRangeModel(seed=5).fit(x, y).kernel_sigma)
    for gamma, kernel_sigma in ((0.01, 50.0), (1e6, 0.02), (1.0, 5.0)):  # too smooth, overfitting, too stiff
        assert cv < test_mse(LssvmRangeModel(gamma, kernel_sigma))
    assert cv < 0.2**2 * 1.15  # near the noise floor


def test_large_training_sets_are_subsampled_and_clamped():
    rng = np.random.default_rng(6)
    x = rng.uniform(140, 255, 2000)
    model = LssvmRangeModel(max_train_samples=300, cv_samples=100).fit(x, (255 - x) / 12)
    assert model.support_x.size == 300
    # readings outside the training range are clamped to it, never extrapolated back toward b
    lo, hi = model.input_range
    assert model.predict_distance_m(np.array([0.0]))[0] == model.predict_distance_m(np.array([lo]))[0]
    assert np.isnan(model.predict_distance_m(np.array([np.nan]))[0])
    assert np.all(model.predict_distance_m(np.array([hi, 255.0])) >= 0)


@pytest.mark.parametrize("kwargs", [{"gamma": 1.0}, {"gamma": -1.0, "kernel_sigma": 1.0}, {"folds": 1}])
def test_bad_configuration(kwargs):
    with pytest.raises(ConfigError):
        LssvmRangeModel(**kwargs)


def test_bad_training_data():
    with pytest.raises(ConfigError, match="readings but"):
        LssvmRangeModel().fit(np.ones(20), np.ones(19))
    with pytest.raises(ConfigError, match="at least"):
        LssvmRangeModel().fit(np.array([1.0, np.nan, 3.0]), np.ones(3))
    with pytest.raises(ConfigError, match="not been fitted"):
        LssvmRangeModel().predict_distance_m(np.ones(2))
