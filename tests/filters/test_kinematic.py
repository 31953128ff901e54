"""The song2014 / liu2016 kinematic models: analytic Jacobians against finite
differences, the CT -> straight-line limit, the liu2016 eq. (4)+(5) = eq. (16)
identity."""

import numpy as np
import pytest

from filters.models import kinematic as km


def numeric_jacobian(f, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    f0 = f(x)
    J = np.zeros((f0.size, x.size))
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        J[:, i] = (f(x + d) - f(x - d)) / (2 * eps)
    return J


RNG = np.random.default_rng(3)
STATES = [np.array([10.0, -4.0, 3.0, 1.5, 0.7, 0.2]), np.array([0.0, 0.0, -2.0, 5.0, -2.5, -0.4])]


@pytest.mark.parametrize("x", STATES)
def test_ca_jacobians(x):
    u = np.array([0.8, -0.3])
    _, A, B = km.ca_transition(x, u, 0.1)
    np.testing.assert_allclose(A, numeric_jacobian(lambda s: km.ca_transition(s, u, 0.1)[0], x), atol=1e-8)
    np.testing.assert_allclose(B, numeric_jacobian(lambda v: km.ca_transition(x, v, 0.1)[0], u), atol=1e-8)


@pytest.mark.parametrize("x", STATES)
@pytest.mark.parametrize("w", [0.3, -1.2, 2e-5, 0.0])
def test_ct_jacobians(x, w):
    u = np.array([w])
    _, A, B = km.ct_transition(x, u, 0.1)
    np.testing.assert_allclose(A, numeric_jacobian(lambda s: km.ct_transition(s, u, 0.1)[0], x), atol=1e-7)
    np.testing.assert_allclose(B, numeric_jacobian(lambda v: km.ct_transition(x, v, 0.1)[0], u, eps=1e-7), atol=1e-6)


def test_ct_tends_to_straight_motion():
    x = np.array([1.0, 2.0, 3.0, -1.0, 0.4, 0.0])
    straight, _, _ = km.ca_transition(x, np.zeros(2), 0.1)
    for w in (1e-3, 1e-5, 1e-7, 1e-12, 0.0, -1e-9):
        xt, A, B = km.ct_transition(x, np.array([w]), 0.1)
        assert np.all(np.isfinite(A)) and np.all(np.isfinite(B))
        np.testing.assert_allclose(xt[:4], straight[:4], atol=abs(w) * 0.1 * 5 + 1e-12)
    # the series used near w = 0 matches the closed form where they meet
    T, w = 0.1, 0.99e-3
    S, C, dS, dC = km._turn_coefficients(w, T)
    wt = w * T
    np.testing.assert_allclose([S, C], [np.sin(wt) / w, (1 - np.cos(wt)) / w], rtol=1e-8)
    np.testing.assert_allclose([dS, dC], [(wt * np.cos(wt) - np.sin(wt)) / w**2, (wt * np.sin(wt) - 1 + np.cos(wt)) / w**2], rtol=1e-4, atol=1e-9)


def test_ct_exact_circle():
    # a full circle at constant turn rate comes back to its start
    r, w = 20.0, 0.5
    T = 2 * np.pi / w / 1000
    v = r * w
    x = np.array([0.0, -r, v, 0.0, 0.0, w])
    for _ in range(1000):
        x, _, _ = km.ct_transition(x, np.array([w]), T)
    np.testing.assert_allclose(x[:4], [0.0, -r, v, 0.0], atol=1e-9)


@pytest.mark.parametrize("x", STATES)
def test_observation_jacobian(x):
    z, H = km.position_speed_yaw_observation(x)
    np.testing.assert_allclose(H, numeric_jacobian(lambda s: km.position_speed_yaw_observation(s)[0], x), atol=1e-8)
    zs, Hs = km.position_speed_yaw_observation(x, np.array([2, 3]))
    np.testing.assert_array_equal(zs, z[2:])
    np.testing.assert_array_equal(Hs, H[2:])


def test_current_statistical_eq4_plus_eq5_is_eq16():
    x = np.array([3.0, 2.0, 0.5, -1.0, 4.0, -0.3])
    T, ae, an = 0.1, 1 / 3.0, 1 / 7.0
    Phi = km.current_statistical_transition(T, ae, an)
    U = km.current_statistical_input(T, ae, an, x[km.AE], x[km.AN])
    pred, Phi16 = km.current_statistical_prediction(x, T)
    np.testing.assert_allclose(Phi @ x + U, pred, atol=1e-12)
    np.testing.assert_allclose(Phi16, numeric_jacobian(lambda s: km.current_statistical_prediction(s, T)[0], x), atol=1e-9)


def test_current_statistical_noise_is_symmetric_psd():
    Q = km.current_statistical_process_noise(0.1, 1.0, 0.5, 2.0, 3.0)
    np.testing.assert_allclose(Q, Q.T)
    assert np.linalg.eigvalsh(Q).min() > -1e-15


@pytest.mark.parametrize("x", [np.array([0, 3.0, 0.5, 0, 4.0, -0.2]), np.array([0, -2.0, 1.0, 0, 0.5, 0.3])])
def test_dr_observation_jacobian_and_sign(x):
    z, H = km.dr_observation(x, 0.1)
    np.testing.assert_allclose(H, numeric_jacobian(lambda s: km.dr_observation(s, 0.1)[0], x), atol=1e-8)
    # rate is d/dt atan2(v_n, v_e) (yaw from east, counter-clockwise)
    dt = 1e-6
    v0 = np.array([x[km.CVE], x[km.CVN]])
    v1 = v0 + dt * np.array([x[km.AE], x[km.AN]])
    rate = (np.arctan2(v1[1], v1[0]) - np.arctan2(v0[1], v0[0])) / dt
    assert z[0] == pytest.approx(rate, rel=1e-4)
    assert z[1] == pytest.approx(0.1 * np.hypot(*v0))


def test_observation_of_a_stack_is_each_state_observed():
    X = np.array(STATES)
    rows = np.array([0, 2, 3])
    z, H = km.position_speed_yaw_observation(X, rows)
    for x, zi, Hi in zip(X, z, H):
        z1, H1 = km.position_speed_yaw_observation(x, rows)
        np.testing.assert_allclose(zi, z1, rtol=1e-15, atol=1e-15)
        np.testing.assert_allclose(Hi, H1, rtol=1e-15, atol=1e-15)
