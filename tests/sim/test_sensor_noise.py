"""Sensor noise statistics over long runs: sample STD within 10 % of the
configured value (sensor minus truth)."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.sim import default_params, simulate
from graphpos.sim.rss import ENVIRONMENTS

LONG_S = 600.0  # seconds: long enough for the statistics, about a second to build

NO_BIAS = {"imu": {"accel_bias_sigma_mps2": 0.0, "gyro_bias_sigma_dps": 0.0}}


def within_10pct(measured: float, configured: float) -> None:
    assert measured == pytest.approx(configured, rel=0.10), (measured, configured)


def test_imu_white_noise_without_bias():
    drive = simulate("paper-comprehensive", "lane-change-curve", seed=21, duration_s=LONG_S, overrides=NO_BIAS)
    p = default_params("paper-comprehensive")["imu"]
    truth, imu = drive.truth, drive.imu
    assert np.array_equal(truth.t_s, imu.t_s)
    within_10pct(np.std(imu.accel_x_mps2 - truth.accel_x_mps2), p["accel_sigma_mps2"])
    within_10pct(np.std(imu.accel_y_mps2 - truth.accel_y_mps2), p["accel_sigma_mps2"])
    within_10pct(np.std(imu.yaw_rate_radps - truth.yaw_rate_radps), np.deg2rad(p["gyro_sigma_dps"]))


def test_imu_noise_with_default_bias(long_straight):
    """With the slowly varying biases on, the white part shows in first differences."""
    p = long_straight.params["imu"]
    truth, imu = long_straight.truth, long_straight.imu
    for col, sigma in (("accel_x_mps2", p["accel_sigma_mps2"]), ("accel_y_mps2", p["accel_sigma_mps2"]),
                       ("yaw_rate_radps", np.deg2rad(p["gyro_sigma_dps"]))):
        err = imu[col] - truth[col]
        within_10pct(np.std(np.diff(err)) / np.sqrt(2.0), sigma)
        # the bias makes the error's mean drift away from zero, but slowly
        assert abs(np.mean(err)) < 5 * max(p["accel_bias_sigma_mps2"], np.deg2rad(p["gyro_bias_sigma_dps"]))


def test_imu_bias_is_gauss_markov():
    """Bias alone (no white noise, short correlation time): STD = sigma, correlation exp(-lag/tau)."""
    tau = 2.0
    over = {"imu": {"accel_sigma_mps2": 0.0, "gyro_sigma_dps": 0.0, "accel_bias_sigma_mps2": 0.05, "accel_bias_tau_s": tau,
                    "gyro_bias_sigma_dps": 0.1, "gyro_bias_tau_s": tau}}
    drive = simulate("paper-straight", seed=22, duration_s=LONG_S, overrides=over)
    bias = drive.imu.accel_x_mps2 - drive.truth.accel_x_mps2
    within_10pct(np.std(bias), 0.05)
    within_10pct(np.std(drive.imu.yaw_rate_radps - drive.truth.yaw_rate_radps), np.deg2rad(0.1))
    lag = int(tau * 100)
    corr = np.corrcoef(bias[:-lag], bias[lag:])[0, 1]
    assert corr == pytest.approx(np.exp(-1.0), abs=0.1)


def test_wheel_noise_and_scale(long_straight):
    p = long_straight.params["wheel"]
    scale = long_straight.params["realised"]["wheel_scale_error"]
    truth = long_straight.truth
    speed = np.hypot(truth.v_east_mps, truth.v_north_mps)
    err = long_straight.wheel.speed_mps - speed * (1 + scale)
    within_10pct(np.std(err), p["sigma_mps"])
    fitted = np.sum(long_straight.wheel.speed_mps * speed) / np.sum(speed**2) - 1
    assert fitted == pytest.approx(scale, abs=0.002)


def wrapped(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_compass_noise_without_disturbances():
    drive = simulate("paper-imm", "accel", seed=23, duration_s=LONG_S, overrides={"compass": {"disturbances_per_km": 0.0}})
    comp = drive.compass
    truth_yaw = np.interp(comp.t_s, drive.truth.t_s, drive.truth.yaw_rad)
    assert np.all(np.abs(comp.yaw_rad) <= np.pi)
    within_10pct(np.std(wrapped(comp.yaw_rad - truth_yaw)), np.deg2rad(drive.params["compass"]["sigma_deg"]))


def test_compass_disturbances_are_fixed_on_the_road():
    """The same road position gives the same disturbance on every pass."""
    over = {"compass": {"sigma_deg": 0.0, "disturbances_per_km": 50.0}}
    drive = simulate("paper-straight", seed=24, duration_s=LONG_S, overrides=over)
    comp = drive.compass
    err = wrapped(comp.yaw_rad - np.interp(comp.t_s, drive.truth.t_s, drive.truth.yaw_rad))
    east = np.interp(comp.t_s, drive.truth.t_s, drive.truth.east_m)
    assert np.abs(err).max() > np.deg2rad(1.0)
    passes = drive.window("in_tunnel")
    grid = np.linspace(10, 110, 50)
    profiles = []
    for w in passes[:3]:
        m = w.contains(comp.t_s)
        order = np.argsort(east[m])
        profiles.append(np.interp(grid, east[m][order], err[m][order]))
    assert np.allclose(profiles[0], profiles[1], atol=np.deg2rad(0.3))
    assert np.allclose(profiles[0], profiles[2], atol=np.deg2rad(0.3))


def test_gnss_open_and_street(long_urban):
    zones = default_params("urban-rsu-gnss")["gnss"]["zones"]
    over = {"gnss": {"zones": {"open": {"wander_m": 0.0}, "street": {"wander_m": 0.0, "tail_dof": 0.0, "bias_m": 0.0}}}}
    drive = simulate("urban-rsu-gnss", seed=25, duration_s=3 * LONG_S, overrides=over)
    g = drive.gnss
    te = np.interp(g.t_s, drive.truth.t_s, drive.truth.east_m)
    tn = np.interp(g.t_s, drive.truth.t_s, drive.truth.north_m)
    for zone in ("open", "street"):
        m = np.zeros(g.t_s.size, bool)
        for w in drive.window(f"zone:{zone}"):
            m |= w.contains(g.t_s)
        assert m.sum() > 300
        err = np.concatenate([g.east_m[m] - te[m], g.north_m[m] - tn[m]])
        within_10pct(np.std(err), zones[zone]["sigma_m"])
        assert np.allclose(g.sigma_m[m], zones[zone]["sigma_m"])
    # default street model: biased to the left of the road, heavier tails than Gaussian
    g = long_urban.gnss
    (first,) = long_urban.window("zone:street")[:1]
    te = np.interp(g.t_s, long_urban.truth.t_s, long_urban.truth.east_m)
    tn = np.interp(g.t_s, long_urban.truth.t_s, long_urban.truth.north_m)
    m = np.zeros(g.t_s.size, bool)
    for w in long_urban.window("zone:street"):
        m |= w.contains(g.t_s)
    err = np.hypot(g.east_m[m] - te[m], g.north_m[m] - tn[m])
    assert np.sqrt(np.mean(err**2)) > 1.5 * zones["street"]["sigma_m"]


def test_rsu_fix_and_range_noise(long_urban):
    rsu = long_urban.rsu
    sigma = long_urban.params["rsu"]["sigma_m"]
    te = np.interp(rsu.t_s, long_urban.truth.t_s, long_urban.truth.east_m)
    tn = np.interp(rsu.t_s, long_urban.truth.t_s, long_urban.truth.north_m)
    assert rsu.t_s.size > 150
    within_10pct(np.std(np.concatenate([rsu.east_m - te, rsu.north_m - tn])), sigma)
    pos = long_urban.rsus
    idx = rsu.rsu_id.astype(int) - 1
    true_range = np.hypot(te - pos.east_m[idx], tn - pos.north_m[idx])
    within_10pct(np.std(rsu.range_m - true_range), sigma)
    assert np.all(rsu.sigma_m == sigma)


def test_rfid_rss_fading_and_detection():
    """Within the reliable range: per-reading fading (tag shadowing removed
    per tag) has the RSS law's sigma, and 1 - read_failure_probability of
    the tags in reach are heard."""
    over = {"rfid": {"outlier_probability": 0.0}}
    drive = simulate("paper-straight", seed=26, duration_s=LONG_S, overrides=over)
    env = ENVIRONMENTS["tunnel"]
    rfid = drive.rfid
    assert np.isnan(rfid.range_m).all()
    assert rfid.true_range_m.max() <= env.max_range_m
    near = rfid.true_range_m <= env.reliable_range_m
    resid = rfid.rss - env.mean_rss(rfid.true_range_m)
    ids = rfid.tag_id.astype(int)
    per_tag = np.array([resid[near & (ids == i)].mean() for i in ids[near]])
    within_10pct(np.std(resid[near] - per_tag), env.units_per_db * env.fading_db)
    # detection: count tags within the reliable range at each read from the truth
    tags = drive.tags
    reads = np.unique(rfid.t_s)
    k = np.searchsorted(drive.truth.t_s, reads)
    d = np.hypot(drive.truth.east_m[k, None] - tags.east_m[None], drive.truth.north_m[k, None] - tags.north_m[None])
    in_reach = (d <= env.reliable_range_m).sum()
    heard = near.sum()
    assert heard / in_reach == pytest.approx(1 - drive.params["rfid"]["read_failure_probability"], abs=0.02)
    # beyond the reliable range detection falls off: fewer than in reach are heard
    far_reach = ((d > env.reliable_range_m) & (d <= env.max_range_m)).sum()
    assert (~near).sum() < 0.7 * far_reach


def test_rfid_outliers():
    """Outliers (an extra N(0, outlier_sigma_db)) make wild readings several times more common."""
    env = ENVIRONMENTS["tunnel"]
    limit = 3 * env.units_per_db * np.hypot(2 * env.fading_db, env.shadowing_db)

    def wild_fraction(p: float) -> float:
        drive = simulate("paper-straight", seed=27, duration_s=LONG_S, overrides={"rfid": {"outlier_probability": p}})
        resid = drive.rfid.rss - env.mean_rss(drive.rfid.true_range_m)
        return float(np.mean(np.abs(resid) > limit))

    assert wild_fraction(0.2) > 5 * max(wild_fraction(0.0), 0.002)


@pytest.mark.slow
def test_gnss_street_multipath_over_an_hour():
    """liu2016's street: fixes biased left of the road by bias_m on average,
    heavier-tailed than a Gaussian (kurtosis well above 3)."""
    drive = simulate("urban-rsu-gnss", seed=28, duration_s=3600.0)
    z = drive.params["gnss"]["zones"]["street"]
    g, truth = drive.gnss, drive.truth
    k = np.searchsorted(truth.t_s, g.t_s)
    m = np.zeros(g.t_s.size, bool)
    for w in drive.window("zone:street"):
        m |= w.contains(g.t_s)
    de, dn = g.east_m[m] - truth.east_m[k][m], g.north_m[m] - truth.north_m[k][m]
    # the street runs north after the left turn: the road's left is west (on both passes: bias fixed in space)
    assert -np.mean(de) == pytest.approx(z["bias_m"], abs=0.5)
    white = np.diff(dn)  # differencing removes the slow wander and the bias
    kurtosis = np.mean((white - white.mean()) ** 4) / np.var(white) ** 2
    assert kurtosis > 4.0
