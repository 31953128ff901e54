"""song2014: LMS-federated positioning, STEKF, IMM and the fusion estimators
on small synthetic drives built here (exact or seeded-noise sensors)."""

import math

import numpy as np
import pytest

from filters.core import ekf, imm, stekf
from filters.lms import LmsFederated, LmsFederatedConfig
from filters.song2014 import EkfCa, ImmStekf, Song2014Config, StekfCa
from graphpos.drive import Channel, Drive, TagMap, Window
from graphpos.ranging.model import LinearCalibration

IDENTITY = LinearCalibration(sigma0_m=0.5)


def make_drive(duration_s=40.0, speed_mps=2.0, accel_mps2=0.0, turn_start_s=None, yaw_rate_radps=0.0,
               range_sigma_m=0.0, sensor_noise=False, seed=0, bad_tags=()):
    """A tunnel drive: straight (then optionally a constant-rate turn), tags on
    both walls every 6 m of path, 7.5 m apart; RFID 1 Hz with ranges within
    9 m, IMU/wheel 100 Hz, compass 10 Hz."""
    rng = np.random.default_rng(seed)
    dt = 0.001
    t = np.arange(0.0, duration_s + 1e-9, dt)
    v = speed_mps + accel_mps2 * t
    w = np.zeros_like(t)
    if turn_start_s is not None:
        w[t >= turn_start_s] = yaw_rate_radps
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)]) + 0.3
    ve, vn = v * np.cos(yaw), v * np.sin(yaw)
    e = np.concatenate([[0.0], np.cumsum(0.5 * (ve[1:] + ve[:-1]) * dt)])
    n = np.concatenate([[0.0], np.cumsum(0.5 * (vn[1:] + vn[:-1]) * dt)])
    # tags: every 6 m of arc length, both walls
    s = np.concatenate([[0.0], np.cumsum(v[1:] * dt)])
    marks = np.arange(-6.0, s[-1] + 12.0, 6.0)
    idx = np.clip(np.searchsorted(s, marks), 0, len(s) - 1)
    extra = marks - s[idx]  # extend straight beyond the ends
    te = e[idx] + extra * np.cos(yaw[idx])
    tn = n[idx] + extra * np.sin(yaw[idx])
    normal = np.column_stack([-np.sin(yaw[idx]), np.cos(yaw[idx])])
    tags_e = np.concatenate([te + 3.75 * normal[:, 0], te - 3.75 * normal[:, 0]])
    tags_n = np.concatenate([tn + 3.75 * normal[:, 1], tn - 3.75 * normal[:, 1]])
    m = len(marks)
    tags = TagMap(np.arange(2 * m), tags_e, tags_n, np.r_[np.ones(m), -np.ones(m)], np.zeros(2 * m))
    k100 = np.arange(0, len(t), 10)
    k10 = np.arange(0, len(t), 100)
    noise = (lambda sd, k: rng.normal(0, sd, k.size)) if sensor_noise else (lambda sd, k: np.zeros(k.size))
    accel = np.gradient(v, dt)
    imu = Channel("imu", {"t_s": t[k100], "accel_x_mps2": accel[k100] + noise(0.1, k100),
                          "accel_y_mps2": (v * w)[k100] + noise(0.1, k100),
                          "yaw_rate_radps": w[k100] + noise(0.2 * math.pi / 180, k100)})
    wheel = Channel("wheel", {"t_s": t[k100], "speed_mps": v[k100] + noise(0.05, k100)})
    compass = Channel("compass", {"t_s": t[k10], "yaw_rad": (yaw[k10] + noise(2 * math.pi / 180, k10) + math.pi) % (2 * math.pi) - math.pi})
    rt, rid, rr, rtrue = [], [], [], []
    for k in np.arange(500, len(t), 1000):
        d = np.hypot(tags_e - e[k], tags_n - n[k])
        for j in np.flatnonzero(d < 9.0):
            r = d[j] + (rng.normal(0, range_sigma_m) if range_sigma_m else 0.0)
            if j in bad_tags:
                r += 8.0
            rt.append(t[k]); rid.append(j); rr.append(max(r, 0.0)); rtrue.append(d[j])
    rfid = Channel("rfid", {"t_s": rt, "tag_id": rid, "range_m": rr, "true_range_m": rtrue})
    truth = Channel("truth", {"t_s": t[k100], "east_m": e[k100], "north_m": n[k100], "v_east_mps": ve[k100],
                              "v_north_mps": vn[k100], "yaw_rad": yaw[k100]})
    windows = (Window("curve", turn_start_s, duration_s),) if turn_start_s is not None else ()
    return Drive("synthetic", {"imu": imu, "wheel": wheel, "compass": compass, "rfid": rfid, "truth": truth},
                 tags=tags, windows=windows)


def errors(est, drive, start_s=0.0, end_s=np.inf):
    tr = drive.truth
    e = np.interp(est.t_s, tr.t_s, tr.east_m) - est.east_m
    n = np.interp(est.t_s, tr.t_s, tr.north_m) - est.north_m
    keep = (est.t_s >= start_s) & (est.t_s <= end_s)
    return np.hypot(e, n)[keep]


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


# -- LMS-federated ------------------------------------------------------------

def test_lms_federated_zero_error_on_exact_ranges():
    drive = make_drive(duration_s=20.0)
    est = LmsFederated(range_model=IDENTITY).run(drive)
    assert len(est) >= 18
    assert errors(est, drive).max() < 1e-6


def test_lms_federated_isolates_a_failing_tag():
    drive = make_drive(duration_s=30.0, range_sigma_m=0.3, bad_tags=(3, 7, 11), seed=1)
    federated = rms(errors(LmsFederated(range_model=IDENTITY).run(drive), drive))
    # equal coefficients, pass-through local and global filters: plain least squares
    plain_cfg = LmsFederatedConfig(global_taps=1, local_taps=1, local_step=1e-12, global_step=0.0, coefficient_feedback=False)
    plain = rms(errors(LmsFederated(plain_cfg, range_model=IDENTITY).run(drive), drive))
    assert federated < 0.5 * plain


# -- STEKF and IMM cores --------------------------------------------------------

def _random_problem(seed=0):
    rng = np.random.default_rng(seed)
    n, m = 6, 4
    L = rng.normal(size=(n, n))
    P = L @ L.T + np.eye(n)
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    Q = np.diag(rng.uniform(0.01, 0.1, n))
    H = rng.normal(size=(m, n))
    return rng.normal(size=n), A, P, Q, rng.normal(size=m), H @ rng.normal(size=n), H, rng.uniform(0.1, 1, m)


def _stacked(*arrays):
    return [a[None] for a in arrays]


def test_stekf_without_fading_is_the_ekf():
    x, A, P, Q, z, z_pred, H, R = _random_problem()
    rows = np.arange(4)
    xs, As, Ps, Qs, zps, Hs = _stacked(x, A, P, Q, z_pred, H)
    s = stekf.step(xs, As, Ps, Qs, z, zps, Hs, np.diag(R), rows, stekf.FadingMemory(4), stekf.FadingConfig(enabled=False))
    _, P_pred = ekf.predict(x, A, P, Q)
    ref = ekf.update(x, P_pred, z, z_pred, H, R)
    np.testing.assert_allclose(s.x[0], ref.x, rtol=1e-9)
    np.testing.assert_allclose(s.P[0], ref.P, rtol=1e-9, atol=1e-12)
    assert s.fading[0] == 1.0


def test_stacked_filters_step_independently():
    a, b = _random_problem(2), _random_problem(3)
    rows = np.arange(4)
    cfg = stekf.FadingConfig()
    z, R = a[4], np.diag(a[7])
    both = stekf.step(*(np.stack([p, q]) for p, q in zip(a[:4], b[:4])), z, np.stack([a[5], b[5]]),
                      np.stack([a[6], b[6]]), R, rows, stekf.FadingMemory(4, 2), cfg)
    for k, prob in enumerate((a, b)):
        x, A, P, Q, _, z_pred, H, _ = prob
        one = stekf.step(*_stacked(x, A, P, Q), z, z_pred[None], H[None], R, rows, stekf.FadingMemory(4), cfg)
        np.testing.assert_allclose(both.x[k], one.x[0], rtol=1e-12)
        np.testing.assert_allclose(both.fading[k], one.fading[0], rtol=1e-12)


def test_fading_factor_grows_with_the_innovation():
    x, A, P, Q, z, z_pred, H, R = _random_problem(1)
    rows = np.arange(4)
    cfg = stekf.FadingConfig()
    args = _stacked(x, A, P, Q)
    small = stekf.step(*args, z_pred + 1e-3, z_pred[None], H[None], np.diag(R), rows, stekf.FadingMemory(4), cfg)
    large = stekf.step(*args, z_pred + 100.0, z_pred[None], H[None], np.diag(R), rows, stekf.FadingMemory(4), cfg)
    assert small.fading[0] == 1.0
    assert large.fading[0] > 10.0
    assert np.trace(large.P[0]) > np.trace(small.P[0])


def test_imm_probabilities_follow_the_likelihoods():
    pi = imm.validate_markov(np.array([[0.9, 0.1], [0.1, 0.9]]))
    mu = np.array([0.5, 0.5])
    x0, P0, predicted = imm.mix(np.array([np.zeros(2), np.ones(2)]), np.array([np.eye(2)] * 2), mu, pi)
    # mixing of eq. 26-27: weights pi_ji mu_j / mu_i
    np.testing.assert_allclose(x0[0], [0.1, 0.1])
    np.testing.assert_allclose(P0[0], np.eye(2) + 0.9 * 0.1 * np.ones((2, 2)))
    ll = imm.log_likelihood(np.array([[3.0], [0.1]]), np.array([np.eye(1)] * 2))
    post = imm.update_probabilities(predicted, ll)
    assert post[1] > 0.9 and np.isclose(post.sum(), 1.0)
    with pytest.raises(ValueError):
        imm.validate_markov(np.array([[0.5, 0.6], [0.1, 0.9]]))


# -- the fusion estimators ----------------------------------------------------------

@pytest.mark.parametrize("cls", [EkfCa, StekfCa, ImmStekf])
def test_zero_error_on_noiseless_straight_drive(cls):
    drive = make_drive(duration_s=20.0)
    est = cls(range_model=IDENTITY).run(drive)
    assert len(est) > 150 and est.has_velocity
    assert errors(est, drive).max() < 1e-6


def test_imm_with_two_identical_models_is_the_single_filter():
    drive = make_drive(duration_s=25.0, turn_start_s=10.0, yaw_rate_radps=0.1, range_sigma_m=0.5, sensor_noise=True)
    single = StekfCa(range_model=IDENTITY).run(drive)
    twin = ImmStekf(Song2014Config(models=("ca", "ca")), range_model=IDENTITY).run(drive)
    np.testing.assert_allclose(twin.position, single.position, atol=1e-8)
    np.testing.assert_allclose(twin.cov_en_m2, single.cov_en_m2, atol=1e-8)


def test_imm_reports_model_probabilities():
    drive = make_drive(duration_s=30.0, turn_start_s=15.0, yaw_rate_radps=0.12, range_sigma_m=0.8,
                       sensor_noise=True, seed=4)
    est = ImmStekf(range_model=IDENTITY).run(drive)
    mp = est.diagnostics["model_probabilities"]
    np.testing.assert_array_equal(mp["t_s"], est.t_s)
    ca, ct = np.asarray(mp["ca"]), np.asarray(mp["ct"])
    np.testing.assert_allclose(ca + ct, 1.0)
    assert ((ca > 0) & (ca < 1)).all() and ca.std() > 0.01


@pytest.mark.parametrize("cls", [LmsFederated, ImmStekf])
def test_fast_run_equals_the_process_loop(cls):
    from graphpos.estimator import Estimator

    drive = make_drive(duration_s=20.0, turn_start_s=8.0, yaw_rate_radps=0.1, range_sigma_m=0.5, sensor_noise=True)
    fast = cls(range_model=IDENTITY).run(drive)
    loop = Estimator.run(cls(range_model=IDENTITY), drive)
    np.testing.assert_array_equal(fast.t_s, loop.t_s)
    np.testing.assert_allclose(fast.position, loop.position, rtol=0, atol=1e-12)


# -- simulated paper-imm drives (song2014 §5) -----------------------------------

def _paper_imm(seeds, **overrides):
    from graphpos.sim import simulate

    return [simulate("paper-imm", seed=s, overrides=overrides or None) for s in seeds]


def _window_rms(est, drive, label):
    from eval.metrics import evaluate_estimate

    return evaluate_estimate(drive, est)["windows"][label]["position"]["rms_m"]


def test_lms_federated_beats_multilateration_in_the_tunnel():
    from filters.song2016 import Multilateration

    drives = _paper_imm(range(4, 8))
    lms = np.mean([_window_rms(LmsFederated().run(d), d, "in_tunnel") for d in drives])
    multi = np.mean([_window_rms(Multilateration().run(d), d, "in_tunnel") for d in drives])
    assert lms < 0.95 * multi


def test_imm_beats_stekf_beats_ekf_on_the_curve_with_uncompensated_accelerometers():
    # Accelerometer bias 0.2 m/s^2 (1-sigma): an in-car MEMS unit whose
    # mounting tilt and the road grade leak gravity into a_x, a_y — the
    # "unrealistic noise description" under which song2014 §5.3.2 compares
    # the filters. (With the simulator's default 0.02 m/s^2 the three are
    # within 0.15 m of each other; see the benchmark.)
    drives = _paper_imm(range(4, 8), imu={"accel_bias_sigma_mps2": 0.2})
    curve = {cls.name: np.mean([_window_rms(cls().run(d), d, "curve") for d in drives]) for cls in (EkfCa, StekfCa, ImmStekf)}
    assert curve["imm-stekf"] < curve["stekf-ca"] < curve["ekf-ca"], curve
