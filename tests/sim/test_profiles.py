"""Sensor profiles (``ideal``, ``realistic``) and the DGPS fixes on the paper scenarios' approach.

The realistic profile's per-drive error terms are checked against the truth
(each drawn value within its bounds and visible in the samples), the ideal
profile against samples pinned before profiles existed, and the profile's
streams for isolation (the realistic drive's other samples are the ideal
drive's).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphpos.errors import ConfigError
from graphpos.sim import SCENARIOS, default_params, load_config, simulate
from graphpos.sim.params import PROFILES

PAPER = [name for name in SCENARIOS if name.startswith("paper-")]
LONG_S = 600.0

#: Samples of default drives (seed 3, one pass) generated before sensor
#: profiles and the approach DGPS existed: (scenario, channel, column, rows, values).
PINNED = [
    ("paper-straight", "imu", "accel_x_mps2", [0, 2533, 5066, 7600],
     [-0.16242103804147556, 0.17196953102069226, -0.025067226658809363, -0.006137437739885445]),
    ("paper-straight", "imu", "accel_y_mps2", [0, 2533, 5066, 7600],
     [0.043407866666651106, -0.028668107609074525, 0.2165781189754391, -0.047848428938699346]),
    ("paper-straight", "imu", "yaw_rate_radps", [0, 2533, 5066, 7600],
     [-0.0016010059613524416, -0.005394396535694501, 0.0018529358023049221, 0.0015122542855028512]),
    ("paper-straight", "wheel", "speed_mps", [0, 2533, 5066, 7600],
     [1.9265888647930822, 1.991586323753115, 1.90426229902739, 2.0258126899811333]),
    ("paper-straight", "compass", "yaw_rad", [0, 253, 506, 760],
     [0.009313253538021371, -0.006852202714503708, -0.017100372263211483, -0.011260841638329744]),
    ("paper-straight", "rfid", "tag_id", [0, 87, 175, 263], [2.0, 14.0, 28.0, 42.0]),
    ("paper-straight", "rfid", "rss", [0, 87, 175, 263], [163.0, 195.0, 180.0, 166.0]),
    ("urban-rsu-gnss", "imu", "yaw_rate_radps", [0, 6299, 12598, 18897],
     [-0.0024216126731404306, -0.0013527883550856963, -0.0026031017344154794, -0.004239246199773847]),
    ("urban-rsu-gnss", "wheel", "speed_mps", [0, 6299, 12598, 18897],
     [5.489491210950183, 5.5769581405073865, 5.613887665817554, 5.540913772930516]),
    ("urban-rsu-gnss", "rsu", "range_m", [0, 23, 47, 71],
     [28.648345691891915, 15.03585788236823, 5.165882453795329, 24.70942405489355]),
    ("urban-rsu-gnss", "gnss", "east_m", [0, 38, 77, 116],
     [0.08047549209867333, 210.2163479223922, 728.2839994722816, 729.4341529634958]),
    ("urban-rsu-gnss", "gnss", "north_m", [0, 38, 77, 116],
     [-1.6904670157865243, -1.7361251193118883, 102.96190369215729, 320.0324190513569]),
]

#: Bounds of the realistic profile's drawn terms (the task's figures).
BIAS_MAX_DPS, YAW_SCALE_MAX, WHEEL_SCALE_MAX, RANGE_SCALE = 0.5, 0.30, 0.10, (1.05, 1.08)


@pytest.fixture(scope="module")
def realistic_curve():
    """paper-comprehensive with curves and U-turns, 10 minutes, realistic, Gauss-Markov gyro bias off."""
    return simulate("paper-comprehensive", "lane-change-curve", seed=31, duration_s=LONG_S, profile="realistic",
                    overrides={"imu": {"gyro_bias_sigma_dps": 0.0}})


def truth_at(drive, t_s, column):
    return np.interp(t_s, drive.truth.t_s, drive.truth[column])


# -- the profiles' parameters ---------------------------------------------------


def test_ideal_is_the_default_and_has_no_profile_error():
    for name in SCENARIOS:
        p = default_params(name)
        assert p["profile"] == "ideal" and default_params(name, "ideal") == p
        assert p["imu"]["gyro_turn_on_bias_max_dps"] == 0.0 and p["imu"]["yaw_rate_scale_error_max"] == 0.0
        assert p["wheel"]["scale_error_max"] == 0.0
        if "rfid" in p:
            assert p["rfid"]["reports_range"] is False and p["rfid"]["range_outlier_probability"] == 0.0
    d = simulate("paper-straight", seed=3)
    r = d.params["realised"]
    assert d.params["profile"] == "ideal"
    assert (r["gyro_turn_on_bias_dps"], r["yaw_rate_scale_error"], r["wheel_profile_scale_error"], r["range_scale"],
            r["range_outliers"]) == (0.0, 0.0, 0.0, 1.0, 0)
    assert np.isnan(d.rfid.range_m).all()


def test_realistic_parameters():
    assert set(PROFILES) >= {"ideal", "realistic"}
    p = default_params("paper-straight", "realistic")
    assert p["profile"] == "realistic"
    assert p["imu"]["gyro_turn_on_bias_max_dps"] == BIAS_MAX_DPS
    assert p["imu"]["yaw_rate_scale_error_max"] == YAW_SCALE_MAX
    assert p["wheel"]["scale_error_max"] == WHEEL_SCALE_MAX
    assert (p["rfid"]["range_scale_min"], p["rfid"]["range_scale_max"]) == RANGE_SCALE
    assert p["rfid"]["reports_range"] is True and 0.02 <= p["rfid"]["range_outlier_probability"] <= 0.03
    # the other parameters are the ideal ones
    ideal = default_params("paper-straight")
    assert p["compass"] == ideal["compass"] and p["route"] == ideal["route"] and p["gnss_approach"] == ideal["gnss_approach"]
    # no RFID on liu2016's route: the profile's other terms still apply
    urban = default_params("urban-rsu-gnss", "realistic")
    assert "rfid" not in urban and urban["wheel"]["scale_error_max"] == WHEEL_SCALE_MAX


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_drawn_terms_within_bounds_and_spread(name):
    draws = [simulate(name, seed=s, duration_s=2.0, profile="realistic").params["realised"] for s in range(25)]
    bias = np.array([d["gyro_turn_on_bias_dps"] for d in draws])
    yaw = np.array([d["yaw_rate_scale_error"] for d in draws])
    wheel = np.array([d["wheel_profile_scale_error"] for d in draws])
    rng = np.array([d["range_scale"] for d in draws])
    assert np.abs(bias).max() <= BIAS_MAX_DPS and np.ptp(bias) > BIAS_MAX_DPS
    assert np.abs(yaw).max() <= YAW_SCALE_MAX and np.ptp(yaw) > YAW_SCALE_MAX
    assert np.abs(wheel).max() <= WHEEL_SCALE_MAX and np.ptp(wheel) > WHEEL_SCALE_MAX
    if "rfid" in default_params(name):
        assert rng.min() >= RANGE_SCALE[0] and rng.max() <= RANGE_SCALE[1] and np.ptp(rng) > 0.015
    else:
        assert (rng == 1.0).all()
    # the recorded total wheel scale is the profile's term times the small Gaussian one (1-sigma 1 %)
    gaussian = (1 + np.array([d["wheel_scale_error"] for d in draws])) / (1 + wheel) - 1
    assert np.abs(gaussian).max() < 0.05


# -- the realistic terms against the truth ---------------------------------------


def test_gyro_turn_on_bias_and_yaw_rate_scale(realistic_curve):
    d = realistic_curve
    r = d.params["realised"]
    truth = d.truth.yaw_rate_radps
    assert np.ptp(truth) > 0.3  # curves and U-turns: the scale is observable
    # least squares gyro = (1 + s) truth + b
    a = np.column_stack([truth, np.ones_like(truth)])
    (gain, bias), *_ = np.linalg.lstsq(a, d.imu.yaw_rate_radps, rcond=None)
    assert gain - 1 == pytest.approx(r["yaw_rate_scale_error"], abs=0.002)
    assert np.rad2deg(bias) == pytest.approx(r["gyro_turn_on_bias_dps"], abs=0.005)
    # the mean error against the scaled truth is the turn-on bias (white noise 0.2 deg/s over 60 000 samples)
    err = d.imu.yaw_rate_radps - (1 + r["yaw_rate_scale_error"]) * truth
    assert np.rad2deg(err.mean()) == pytest.approx(r["gyro_turn_on_bias_dps"], abs=0.005)
    assert np.rad2deg(np.std(err)) == pytest.approx(d.params["imu"]["gyro_sigma_dps"], rel=0.1)


def test_gyro_bias_on_top_of_gauss_markov(long_straight):
    """With the default Gauss-Markov bias on as well, the mean error is the
    turn-on bias within a few Gauss-Markov sigmas."""
    d = simulate("paper-straight", seed=11, duration_s=LONG_S, profile="realistic")
    r = d.params["realised"]
    err = d.imu.yaw_rate_radps - (1 + r["yaw_rate_scale_error"]) * d.truth.yaw_rate_radps
    assert np.rad2deg(err.mean()) == pytest.approx(r["gyro_turn_on_bias_dps"], abs=4 * d.params["imu"]["gyro_bias_sigma_dps"])
    # and exactly the ideal drive's error plus the profile's terms (same imu stream)
    ideal = long_straight.imu.yaw_rate_radps
    added = r["yaw_rate_scale_error"] * d.truth.yaw_rate_radps + np.deg2rad(r["gyro_turn_on_bias_dps"])
    assert np.allclose(d.imu.yaw_rate_radps - ideal, added, rtol=0, atol=1e-12)


def test_wheel_scale(realistic_curve):
    d = realistic_curve
    r = d.params["realised"]
    speed = np.hypot(d.truth.v_east_mps, d.truth.v_north_mps)
    fitted = np.sum(d.wheel.speed_mps * speed) / np.sum(speed**2) - 1
    assert fitted == pytest.approx(r["wheel_scale_error"], abs=0.002)
    assert abs(r["wheel_profile_scale_error"]) <= WHEEL_SCALE_MAX
    gaussian = (1 + r["wheel_scale_error"]) / (1 + r["wheel_profile_scale_error"]) - 1
    assert abs(gaussian) < 5 * d.params["wheel"]["scale_error_sigma"]
    err = d.wheel.speed_mps - speed * (1 + r["wheel_scale_error"])
    assert np.std(err) == pytest.approx(d.params["wheel"]["sigma_mps"], rel=0.1)


def test_ranges_read_long_with_outliers(realistic_curve):
    d = realistic_curve
    p, r = d.params["rfid"], d.params["realised"]
    rfid = d.rfid
    assert np.isfinite(rfid.range_m).all() and np.isfinite(rfid.rss).all() and rfid.t_s.size > 1000
    ratio = rfid.range_m / rfid.true_range_m
    assert np.median(ratio) == pytest.approx(r["range_scale"], abs=0.005)
    resid = rfid.range_m - r["range_scale"] * rfid.true_range_m
    outlier = resid > 1.0  # 2-8 m of excess against 0.15 m of noise
    assert outlier.sum() == r["range_outliers"]
    assert outlier.mean() == pytest.approx(p["range_outlier_probability"], abs=0.01)
    assert resid[outlier].min() > p["range_outlier_min_m"] - 0.75 and resid[outlier].max() < p["range_outlier_max_m"] + 0.75
    assert (resid > -1.0).all()  # outliers only read long
    assert np.std(resid[~outlier]) == pytest.approx(p["range_sigma_m"], rel=0.1)
    # a range-scale calibration on the inliers recovers the scale
    t = rfid.true_range_m[~outlier]
    assert np.sum(rfid.range_m[~outlier] * t) / np.sum(t * t) == pytest.approx(r["range_scale"], abs=0.003)


def test_range_model_fitted_to_a_realistic_drive_recovers_the_scale():
    """The realistic radio reports ranges: the default range model uses them
    and a linear calibration fitted to the drive finds the scale."""
    from graphpos.ranging import drive_models
    from graphpos.ranging.model import LinearCalibration

    d = simulate("paper-straight", seed=4, duration_s=LONG_S, profile="realistic")
    assert isinstance(drive_models.default_range_model(d), LinearCalibration)
    fitted = drive_models.fit_from_drive(d, "linear")
    assert fitted.scale == pytest.approx(d.params["realised"]["range_scale"], abs=0.02)


# -- isolation: the ideal samples do not change ------------------------------------


@pytest.mark.parametrize("name", ["paper-straight", "urban-rsu-gnss"])
def test_ideal_samples_pinned(name):
    drive = simulate(name, seed=3)
    for scenario, channel, column, rows, values in PINNED:
        if scenario == name:
            assert np.allclose(drive.channels[channel][column][rows], values, rtol=1e-9, atol=1e-12), (channel, column)


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_realistic_changes_only_its_terms(name):
    ideal = simulate(name, seed=5, duration_s=150.0)
    real = simulate(name, seed=5, duration_s=150.0, profile="realistic")
    assert set(real.channels) == set(ideal.channels)
    for channel in ("truth", "compass", "gnss", "rsu"):
        if channel in ideal.channels:
            assert real.channels[channel] == ideal.channels[channel], channel
    for column in ("t_s", "accel_x_mps2", "accel_y_mps2"):
        assert np.array_equal(real.imu[column], ideal.imu[column])
    assert np.array_equal(real.wheel.t_s, ideal.wheel.t_s)
    if "rfid" in ideal.channels:
        for column in ("t_s", "tag_id", "rss", "true_range_m", "arrival_s"):
            assert np.array_equal(real.rfid[column], ideal.rfid[column]), column
    assert real.windows == ideal.windows and real.tags == ideal.tags and real.rsus == ideal.rsus
    # the wheel differs by the scale alone (same noise samples)
    r = real.params["realised"]
    speed = real.truth  # truth rate = wheel rate here
    true_speed = np.hypot(speed.v_east_mps, speed.v_north_mps)
    delta = (r["wheel_scale_error"] - ideal.params["realised"]["wheel_scale_error"]) * true_speed
    assert np.allclose(real.wheel.speed_mps - ideal.wheel.speed_mps, delta, rtol=0, atol=1e-12)


def test_one_bound_changes_only_its_term():
    """Each term has its own unit draw: changing one bound leaves the others' values."""
    a = simulate("paper-straight", seed=8, duration_s=2.0, profile="realistic").params["realised"]
    b = simulate("paper-straight", seed=8, duration_s=2.0, profile="realistic",
                 overrides={"imu": {"gyro_turn_on_bias_max_dps": 0.1}}).params["realised"]
    assert b["gyro_turn_on_bias_dps"] == pytest.approx(a["gyro_turn_on_bias_dps"] / 5)
    for key in ("yaw_rate_scale_error", "wheel_profile_scale_error", "range_scale", "wheel_scale_error"):
        assert a[key] == b[key], key


# -- choosing a profile ---------------------------------------------------------


def test_profile_from_config_and_argument(tmp_path):
    f = tmp_path / "real.toml"
    f.write_text('profile = "realistic"\n[wheel]\nscale_error_max = 0.02\n')
    cfg = load_config(f)
    d = simulate("paper-straight", seed=2, duration_s=5.0, overrides=cfg)
    assert d.params["profile"] == "realistic"
    assert d.params["wheel"]["scale_error_max"] == 0.02  # the file changes one term ...
    assert d.params["imu"]["yaw_rate_scale_error_max"] == YAW_SCALE_MAX  # ... and keeps the others
    assert abs(d.params["realised"]["wheel_profile_scale_error"]) <= 0.02
    # the argument wins over the file
    assert simulate("paper-straight", seed=2, duration_s=5.0, overrides=cfg, profile="ideal").params["profile"] == "ideal"
    # a single term can be switched on in the ideal profile
    on = simulate("paper-straight", seed=2, duration_s=60.0, overrides={"rfid": {"reports_range": True}})
    assert np.isfinite(on.rfid.range_m).all() and on.params["realised"]["range_scale"] == 1.0


@pytest.mark.parametrize(
    "kwargs,words",
    [
        ({"profile": "paperish"}, ["unknown sensor profile", "ideal", "realistic"]),
        ({"overrides": {"profile": "nope"}}, ["unknown sensor profile"]),
        ({"overrides": {"profile": 3}}, ["unknown sensor profile"]),
        ({"overrides": {"rfid": {"reports_range": 1}}}, ["rfid.reports_range", "true or false"]),
        ({"overrides": {"gnss_approach": {"enabled": "yes"}}}, ["gnss_approach.enabled", "true or false"]),
        ({"overrides": {"rfid": {"range_scale_min": 1.1}}, "profile": "realistic"}, ["range_scale_min", "range_scale_max"]),
        ({"overrides": {"rfid": {"range_outlier_min_m": 9.0}}}, ["range_outlier_min_m"]),
        ({"overrides": {"imu": {"yaw_rate_scale_error_max": 1.5}}}, ["yaw_rate_scale_error_max", "[0, 0.9]"]),
        ({"overrides": {"rfid": {"range_scale_max": 3.0}}}, ["range_scale_max"]),
        ({"overrides": {"gnss_approach": {"rate_hz": 0.0}}}, ["gnss_approach.rate_hz"]),
    ],
)
def test_bad_profile_settings(kwargs, words):
    with pytest.raises(ConfigError) as info:
        simulate("paper-straight", seed=0, duration_s=5.0, **kwargs)
    for word in words:
        assert word in str(info.value)


@pytest.mark.parametrize("name", ["paper-comprehensive", "urban-rsu-gnss"])
def test_realistic_params_dump_reads_back(name, tmp_path, capsys):
    from graphpos.cli import main

    assert main(["scenarios", "--params", name, "--profile", "realistic"]) == 0
    f = tmp_path / "realistic.toml"
    f.write_text(capsys.readouterr().out)
    cfg = load_config(f)
    assert cfg == default_params(name, "realistic")
    a = simulate(name, seed=1, duration_s=30.0, overrides=cfg)
    b = simulate(name, seed=1, duration_s=30.0, profile="realistic")
    assert a.params == b.params
    for channel in b.channels:
        assert a.channels[channel] == b.channels[channel]


def test_cli_profile_writes_the_api_drive(tmp_path, capsys):
    io = pytest.importorskip("graphpos.io")
    from graphpos.cli import main

    out = tmp_path / "r.mcap"
    assert main(["simulate", "paper-imm", "--seed", "6", "--duration", "40", "--profile", "realistic", "-o", str(out)]) == 0
    capsys.readouterr()
    back = io.read_drive(out)
    ref = simulate("paper-imm", seed=6, duration_s=40.0, profile="realistic")
    assert set(back.channels) == set(ref.channels)
    for name, ch in ref.channels.items():
        assert back.channels[name] == ch, name
    assert back.params == json.loads(json.dumps(ref.params))
    assert back.params["profile"] == "realistic" and back.params["realised"]["range_scale"] >= 1.05


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_realistic_round_trip(name, tmp_path):
    io = pytest.importorskip("graphpos.io")
    drive = simulate(name, seed=9, duration_s=60.0, profile="realistic", rfid_latency_s=(0.2, 1.0),
                     faults={"dropped_samples": {"fraction": 0.02}})
    path = tmp_path / f"{name}.mcap"
    io.write_drive(path, drive)
    back = io.read_drive(path)
    assert set(back.channels) == set(drive.channels)
    for channel, ch in drive.channels.items():
        assert back.channels[channel] == ch, channel
    assert back.params == drive.params


# -- DGPS on the paper scenarios' approach -------------------------------------------


@pytest.mark.parametrize("name", PAPER)
@pytest.mark.parametrize("pattern", ["constant", "accel", "decel"])
def test_paper_gnss_only_before_the_tunnel(name, pattern):
    d = simulate(name, pattern=pattern, seed=4, duration_s=500.0)  # several passes: DGPS only on the first approach
    p = d.params["gnss_approach"]
    assert p == {"enabled": True, "rate_hz": 5.0, "sigma_m": 0.4, "duration_s": 5.0}
    g = d.gnss
    entrance = d.window("in_tunnel")[0].start_s
    approach = d.window("zone:approach")[0]
    assert approach.start_s == 0.0 and entrance > 0.0
    assert g.t_s[0] == 0.0 and g.t_s[-1] < entrance and g.t_s[-1] <= p["duration_s"]
    assert ((g.t_s >= approach.start_s) & (g.t_s <= approach.end_s)).all()
    assert np.allclose(np.diff(g.t_s), 1.0 / p["rate_hz"])
    # every fix up to the entrance or the end of the 5 s
    grid = np.arange(int(p["duration_s"] * p["rate_hz"]) + 1) / p["rate_hz"]
    assert g.t_s.size == (grid < entrance).sum()
    assert np.all(g.sigma_m == p["sigma_m"])
    err = np.hypot(g.east_m - truth_at(d, g.t_s, "east_m"), g.north_m - truth_at(d, g.t_s, "north_m"))
    assert err.max() < 5 * p["sigma_m"]


def test_paper_gnss_noise():
    errs = []
    for seed in range(20):
        d = simulate("paper-straight", seed=seed, duration_s=10.0)
        g = d.gnss
        errs += [g.east_m - truth_at(d, g.t_s, "east_m"), g.north_m - truth_at(d, g.t_s, "north_m")]
    err = np.concatenate(errs)
    assert err.size == 20 * 2 * 26
    assert abs(err.mean()) < 0.05
    assert np.std(err) == pytest.approx(0.4, rel=0.1)


def test_paper_gnss_settings():
    off = simulate("paper-straight", seed=1, overrides={"gnss_approach": {"enabled": False}})
    assert "gnss" not in off.channels
    on = simulate("paper-straight", seed=1)
    for channel in off.channels:  # its own stream: switching it off changes nothing else
        assert on.channels[channel] == off.channels[channel]
    fast = simulate("paper-straight", seed=1, overrides={"gnss_approach": {"rate_hz": 10.0, "sigma_m": 0.3, "duration_s": 20.0}})
    entrance = fast.window("in_tunnel")[0].start_s
    assert fast.gnss.t_s[-1] < entrance and fast.gnss.t_s.size == int(entrance * 10.0)  # stops at the portal
    assert np.all(fast.gnss.sigma_m == 0.3)
    short = simulate("paper-straight", seed=1, duration_s=1.0)
    assert short.gnss.t_s[-1] == 1.0


def test_scenarios_with_their_own_gnss_are_unchanged():
    for name in SCENARIOS:
        if not name.startswith("paper-"):
            assert "gnss_approach" not in default_params(name)
    with pytest.raises(ConfigError, match="gnss_approach"):
        simulate("long-tunnel", seed=0, duration_s=5.0, overrides={"gnss_approach": {"enabled": False}})
    urban = simulate("urban-rsu-gnss", seed=2)
    assert len(urban.gnss) > 100  # liu2016's zone model, pinned in test_ideal_samples_pinned


@pytest.mark.parametrize("name", list(SCENARIOS))
@pytest.mark.parametrize("profile", ["ideal", "realistic"])
def test_every_channel_valid(name, profile):
    """Every channel passes the drive's validation (Channel validates on
    construction; rebuilding checks it again) and holds finite required values."""
    from graphpos.drive import Channel, Drive

    d = simulate(name, seed=13, duration_s=SCENARIOS[name].default_duration_s + 20.0, profile=profile)
    rebuilt = Drive(name=d.name, channels={k: Channel(k, ch.columns) for k, ch in d.channels.items()},
                    tags=d.tags, rsus=d.rsus, windows=d.windows, params=d.params)
    assert set(rebuilt.channels) == set(d.channels)
    assert d.has("gnss")  # paper-*: the approach DGPS; the others: their own GNSS model
    for ch in d.channels.values():
        assert len(ch) > 0, ch.kind
