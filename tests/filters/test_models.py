"""Every model Jacobian against central finite differences; angle helpers."""

import numpy as np
import pytest

from filters.models import measurements as meas
from filters.models import vehicle
from filters.models.angles import angle_residual, circular_mean, wrap_angle


def numeric_jacobian(f, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((np.atleast_1d(f(x + d)) - np.atleast_1d(f(x - d))) / (2 * eps))
    return np.column_stack(cols)


rng = np.random.default_rng(7)
STATES = [np.array([3.0, -2.0, 4.0, 1.5, 0.7]), np.array([-10.0, 5.0, -1.0, 2.0, 3.1]), rng.normal(size=5) * 5]


@pytest.mark.parametrize("x", STATES)
def test_improved_motion_jacobians(x):
    u = np.array([0.8, -0.3, 0.2])
    dt = 0.1
    _, (F, G) = vehicle.improved_motion(x, u, dt)
    np.testing.assert_allclose(F, numeric_jacobian(lambda s: vehicle.improved_motion(s, u, dt, False)[0], x), atol=1e-8)
    np.testing.assert_allclose(G, numeric_jacobian(lambda v: vehicle.improved_motion(x, v, dt, False)[0], u), atol=1e-8)


def test_improved_motion_is_eq16_in_state_order():
    x = np.array([1.0, 2.0, 3.0, 4.0, np.pi / 2])
    out, _ = vehicle.improved_motion(x, np.array([2.0, 0.0, 0.5]), 0.1)
    # heading north: a_x goes to the north axis
    np.testing.assert_allclose(out, [1.3, 2.0 + 0.4 + 0.01, 3.0, 4.2, np.pi / 2 + 0.05], atol=1e-12)


def test_improved_motion_vectorised_matches_single():
    X = np.array(STATES)
    u = np.array([0.8, -0.3, 0.2])
    out, _ = vehicle.improved_motion(X, u, 0.01, jacobian=False)
    for row, x in zip(out, X):
        np.testing.assert_allclose(row, vehicle.improved_motion(x, u, 0.01, False)[0])


@pytest.mark.parametrize("x", STATES)
def test_rotating_velocity_jacobian(x):
    w, dt = 0.3, 0.1
    _, F = vehicle.rotating_velocity_motion(x, w, dt)
    np.testing.assert_allclose(F, numeric_jacobian(lambda s: vehicle.rotating_velocity_motion(s, w, dt, False)[0], x), atol=1e-8)


def test_rotating_velocity_keeps_speed():
    x = np.array([0.0, 0.0, 3.0, 4.0, 0.9273])
    out, _ = vehicle.rotating_velocity_motion(x, 1.0, 0.5, False)
    assert np.hypot(out[2], out[3]) == pytest.approx(5.0)


def test_random_walk():
    x = np.array([1.0, 2.0])
    out, F = vehicle.random_walk(x, 1.0)
    np.testing.assert_array_equal(out, x)
    np.testing.assert_array_equal(F, np.eye(2))


@pytest.mark.parametrize("x", STATES)
def test_measurement_jacobians(x):
    tags = np.array([[0.0, 3.0], [6.0, -3.0], [12.0, 3.0]])
    for fn in (
        lambda s, j=True: meas.tag_range(s, tags, j),
        lambda s, j=True: meas.wheel_speed(s, j),
        lambda s, j=True: meas.compass_yaw(s, j),
        lambda s, j=True: meas.position_fix(s, j),
    ):
        value, H = fn(x)
        np.testing.assert_allclose(H, numeric_jacobian(lambda s: fn(s, False)[0], x), atol=1e-7)
        np.testing.assert_allclose(np.atleast_1d(value), np.atleast_1d(fn(x, False)[0]))


def test_range_on_two_state_and_stacked():
    tags = np.array([[3.0, 4.0]])
    r, H = meas.tag_range(np.zeros(2), tags)
    assert r[0] == pytest.approx(5.0)
    np.testing.assert_allclose(H, [[-0.6, -0.8]])
    R, _ = meas.tag_range(np.zeros((3, 5)), tags, jacobian=False)
    assert R.shape == (3, 1)


def test_wheel_speed_convention():
    x = np.array([0, 0, 0.0, 2.0, np.pi / 2])
    assert meas.wheel_speed(x)[0] == pytest.approx(2.0)


def test_angles():
    assert wrap_angle(np.pi) == pytest.approx(-np.pi)
    assert angle_residual(np.deg2rad(179.0), np.deg2rad(-179.0)) == pytest.approx(np.deg2rad(-2.0))
    np.testing.assert_allclose(wrap_angle(np.array([3 * np.pi, -3.5 * np.pi])), [-np.pi, 0.5 * np.pi])
    m = circular_mean(np.array([np.pi - 0.1, -np.pi + 0.1]), np.array([0.5, 0.5]))
    assert abs(angle_residual(float(m), np.pi)) < 1e-12
