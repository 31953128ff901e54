"""EKF, UKF and federated-fusion cores against references and each other."""

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints as FpPoints
from filterpy.kalman import UnscentedKalmanFilter as FpUkf

from filters.core import ekf
from filters.core.federated import fuse, share_information
from filters.core.ukf import MerweScaledSigmaPoints, UnscentedKalmanFilter, nearest_positive_definite
from filters.models import measurements as meas
from filters.models import vehicle
from filters.models.angles import angle_residual, circular_mean, wrap_angle

TAGS = np.array([[0.0, 3.0], [6.0, -3.0], [12.0, 3.0], [18.0, -3.0]])


def _fp_mean(sigmas, Wm):
    m = Wm @ sigmas
    m[4] = circular_mean(sigmas[:, 4], Wm)
    return m


def _fp_residual(a, b):
    d = a - b
    d[4] = angle_residual(a[4], b[4])
    return d


def test_ukf_matches_filterpy_step_by_step():
    """Same sigma points, same nonlinear model (eq. 16 + ranges + wheel speed)."""
    rng = np.random.default_rng(3)
    dt, Q = 0.1, np.diag([0.01, 0.01, 0.05, 0.05, 1e-3])
    x0 = np.array([1.0, 0.5, 2.0, 0.3, 3.0])  # yaw near pi: exercises the wrap
    P0 = np.diag([2.0, 2.0, 0.5, 0.5, 0.1])
    fp = FpUkf(5, 4, dt, hx=None, fx=None, points=FpPoints(5, 0.5, 2.0, 0.0), x_mean_fn=_fp_mean, residual_x=_fp_residual)
    fp.x, fp.P, fp.Q = x0.copy(), P0.copy(), Q
    ours = UnscentedKalmanFilter(x0, P0, MerweScaledSigmaPoints(5, 0.5, 2.0, 0.0), angle_states=(4,))
    R = np.array([0.5, 0.5, 0.5, 0.5])
    for step in range(30):
        u = np.array([0.3 * np.sin(step / 5), 0.2, 0.4])
        fp.predict(fx=lambda s, dt: vehicle.improved_motion(s, u, dt, False)[0])
        fp.x[4] = wrap_angle(fp.x[4])
        ours.predict(lambda S: vehicle.improved_motion(S, u, dt, False)[0], Q)
        np.testing.assert_allclose(ours.x, fp.x, atol=1e-9)
        np.testing.assert_allclose(ours.P, fp.P, atol=1e-9)
        if step % 3 == 0:
            z = meas.tag_range(fp.x, TAGS, False)[0] + rng.normal(0, 0.7, 4)
            fp.update(z, R=np.diag(R), hx=lambda s: meas.tag_range(s, TAGS, False)[0])
        else:
            z = np.array([meas.wheel_speed(fp.x, False)[0] + rng.normal(0, 0.1)])
            R1 = np.array([0.01])
            fp.update(z, R=np.diag(R1), hx=lambda s: np.atleast_1d(meas.wheel_speed(s, False)[0]))
        fp.x[4] = wrap_angle(fp.x[4])
        if step % 3 == 0:
            ours.update(z, lambda S: meas.tag_range(S, TAGS, False)[0], R)
        else:
            ours.update(z, lambda S: meas.wheel_speed(S, False)[0][:, None], R1)
        np.testing.assert_allclose(ours.x, fp.x, atol=1e-9)
        np.testing.assert_allclose(ours.P, fp.P, atol=1e-9)


def test_ekf_equals_ukf_on_linear_gaussian():
    rng = np.random.default_rng(5)
    dt = 0.5
    F = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    Q = np.diag([0.01, 0.01, 0.1, 0.1])
    H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    R = np.array([0.4, 0.3])
    x = np.zeros(4)
    P = np.eye(4) * 3.0
    ukf = UnscentedKalmanFilter(x, P, MerweScaledSigmaPoints(4, alpha=0.3))
    for _ in range(40):
        x, P = ekf.predict(F @ x, F, P, Q)
        ukf.predict(lambda S: S @ F.T, Q)
        z = H @ x + rng.normal(size=2)
        res = ekf.update(x, P, z, H @ x, H, R)
        x, P = res.x, res.P
        ukf.update(z, lambda S: S @ H.T, R)
        np.testing.assert_allclose(ukf.x, x, atol=1e-9)
        np.testing.assert_allclose(ukf.P, P, atol=1e-9)


def test_ekf_update_with_angle_residual():
    x = np.array([0.0, 0.0, 0.0, 0.0, np.pi - 0.01])
    P = np.eye(5)
    z_pred, H = meas.compass_yaw(x)
    res = ekf.update(x, P, np.array([-np.pi + 0.01]), np.atleast_1d(z_pred), H, np.array([1.0]), residual=angle_residual)
    assert res.x[4] == pytest.approx(np.pi - 0.01 + 0.01, abs=1e-9)  # half of a 0.02 rad innovation
    assert res.nis == pytest.approx(0.02**2 / 2)


def test_gate():
    nu = np.array([0.1, 5.0, -0.5])
    ok = ekf.gate_scalar_rows(nu, np.ones(3), 0.99)
    np.testing.assert_array_equal(ok, [True, False, True])
    assert ekf.gate_scalar_rows(nu, np.ones(3), 1.0).all()


def test_ukf_gate_drops_outlier_row():
    ukf = UnscentedKalmanFilter(np.zeros(2), np.eye(2) * 0.1, MerweScaledSigmaPoints(2))
    ref = UnscentedKalmanFilter(np.zeros(2), np.eye(2) * 0.1, MerweScaledSigmaPoints(2))
    _, ok = ukf.update(np.array([0.1, 50.0]), lambda S: S, np.array([0.1, 0.1]), gate_probability=0.999)
    np.testing.assert_array_equal(ok, [True, False])
    ref.update(np.array([0.1]), lambda S: S[:, :1], np.array([0.1]))
    np.testing.assert_allclose(ukf.x, ref.x)
    np.testing.assert_allclose(ukf.P, ref.P)


def test_federated_round_trip_and_identical_estimates():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(5, 5))
    P = A @ A.T + np.eye(5)
    x = np.array([1.0, 2.0, 3.0, 4.0, np.pi - 0.05])
    shares = share_information(P, np.eye(5), [0.8, 0.2])
    x_g, P_g = fuse([(x, Pj) for Pj, _ in shares], angle_states=(4,))
    np.testing.assert_allclose(x_g, x, atol=1e-12)
    np.testing.assert_allclose(P_g, P, atol=1e-10)
    # two identical local estimates: the same state, information added
    x_g, P_g = fuse([(x, P), (x, P)], angle_states=(4,))
    np.testing.assert_allclose(x_g, x, atol=1e-12)
    np.testing.assert_allclose(P_g, P / 2, atol=1e-10)
    # fused yaw across +-pi stays near pi
    x2 = x.copy()
    x2[4] = -np.pi + 0.05
    x_g, _ = fuse([(x, np.eye(5)), (x2, np.eye(5))], angle_states=(4,))
    assert abs(angle_residual(x_g[4], np.pi)) < 1e-12
    with pytest.raises(ValueError):
        share_information(P, np.eye(5), [0.5, 0.2])


def test_fusion_equals_information_form():
    """The folded two-estimate form is eq. 36-37's information form."""
    rng = np.random.default_rng(2)
    estimates = []
    for _ in range(3):
        A = rng.normal(size=(5, 5))
        estimates.append((rng.normal(size=5), A @ A.T + 0.1 * np.eye(5)))
    info = sum(np.linalg.inv(P) for _, P in estimates)
    P_ref = np.linalg.inv(info)
    x_ref = P_ref @ sum(np.linalg.inv(P) @ x for x, P in estimates)
    x_g, P_g = fuse(estimates)
    np.testing.assert_allclose(P_g, P_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(x_g, x_ref, rtol=1e-9, atol=1e-12)


def test_stacked_interval_update_equals_sequential_updates_when_linear():
    """One sigma-point draw carried through several steps, with every reading
    of the interval stacked into one update (the FUKF's local filter 2), is
    the step-by-step predict / update sequence exactly for a linear model,
    linear readings and no process noise inside the interval."""
    rng = np.random.default_rng(3)
    F = np.eye(4) + 0.1 * np.diag(np.ones(3), 1)
    H = rng.normal(size=(2, 4))
    R = np.array([0.3, 0.5])
    x0, P0 = rng.normal(size=4), np.eye(4) * 0.5
    zs = rng.normal(size=(3, 2))
    pts = MerweScaledSigmaPoints(4, alpha=0.3)
    seq = UnscentedKalmanFilter(x0, P0, pts)
    for z in zs:
        seq.predict(lambda S: S @ F.T, np.zeros((4, 4)))
        seq.update(z, lambda S: S @ H.T, R)
    batch = UnscentedKalmanFilter(x0, P0, pts)
    states = [pts.sigma_points(x0, P0)]
    for _ in zs:
        states.append(states[-1] @ F.T)
    dx = batch.predict_points(states[-1], np.zeros((4, 4)))
    Z = np.concatenate([S @ H.T for S in states[1:]], axis=1)
    batch.update_points(zs.ravel(), Z, dx, np.tile(R, len(zs)))
    np.testing.assert_allclose(batch.x, seq.x, atol=1e-10)
    np.testing.assert_allclose(batch.P, seq.P, atol=1e-10)


def test_sigma_points_of_a_covariance_that_lost_positive_definiteness():
    """A positive-definite P gives the Cholesky sigma points unchanged; an indefinite one (a tiny negative
    eigenvalue, as a scaled-transform update can leave) gives those of its nearest positive-definite matrix,
    whose weighted spread reproduces P where P is positive and nothing where it is not."""
    pts = MerweScaledSigmaPoints(3, alpha=0.3)
    rng = np.random.default_rng(1)
    A = rng.normal(size=(3, 3))
    P = A @ A.T + 0.1 * np.eye(3)
    L = np.linalg.cholesky(pts.scale * P)
    assert np.array_equal(pts.sigma_points(np.zeros(3), P)[1:4], L.T)
    V = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    bad = (V * np.array([4.0, 1e-3, -1e-9])) @ V.T
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(pts.scale * bad)
    chi = pts.sigma_points(np.ones(3), bad)
    d = chi - np.ones(3)
    spread = (d[1:] * pts.Wc[1:, None]).T @ d[1:]
    fixed = nearest_positive_definite(bad)
    assert np.allclose(spread, fixed, atol=1e-12)
    assert np.allclose(fixed, (V * np.array([4.0, 1e-3, 0.0])) @ V.T, atol=1e-10)
    assert np.linalg.eigvalsh(fixed).min() > 0
