"""liu2016 federated KF on small synthetic urban drives built here."""

import math

import numpy as np
import pytest

from filters.liu2016 import FederatedKf, Liu2016Config
from graphpos.drive import Channel, Drive, RsuMap, Window
from graphpos.errors import ConfigError, MissingChannelError


def make_drive(duration_s=90.0, speed_mps=5.5, yaw_rate_radps=0.0, gnss_sigma_m=0.7, rsu_sigma_m=1.0,
               gnss_bias=None, rsu_all_along=False, sensor_noise=True, seed=0):
    """Open area (GNSS) for the first third, tunnel (RSU fixes, no GNSS) for
    the second, street (GNSS with a multipath bias) for the last; gyro and
    wheel at 100 Hz. ``gnss_bias``: (start_s, end_s, east_bias_m) override."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s + 1e-9, 0.01)
    yaw = 0.2 + yaw_rate_radps * t
    if yaw_rate_radps:
        e = speed_mps / yaw_rate_radps * (np.sin(yaw) - np.sin(0.2))
        n = -speed_mps / yaw_rate_radps * (np.cos(yaw) - np.cos(0.2))
    else:
        e, n = speed_mps * t * math.cos(0.2), speed_mps * t * math.sin(0.2)
    third = duration_s / 3
    noise = (lambda sd, k: rng.normal(0, sd, k)) if sensor_noise else (lambda sd, k: np.zeros(k))
    # MEMS-grade gyro bias and a wheel scale error when noisy: DR drifts
    gyro_bias, wheel_scale = (0.05 * math.pi / 180, 1.01) if sensor_noise else (0.0, 1.0)
    imu = Channel("imu", {"t_s": t, "yaw_rate_radps": yaw_rate_radps + gyro_bias + noise(0.2 * math.pi / 180, t.size)})
    wheel = Channel("wheel", {"t_s": t, "speed_mps": wheel_scale * speed_mps + noise(0.05, t.size)})
    k1 = np.arange(0, t.size, 100)
    tg = t[k1]
    if gnss_bias is None:
        has_gnss = (tg < third) | (tg >= 2 * third)
        bias = np.where(tg >= 2 * third, 3.0, 0.0)
    else:
        has_gnss = np.ones(tg.size, dtype=bool)
        bias = np.where((tg >= gnss_bias[0]) & (tg < gnss_bias[1]), gnss_bias[2], 0.0)
    gnss = Channel("gnss", {"t_s": tg[has_gnss], "east_m": (e[k1] + bias + noise(gnss_sigma_m, k1.size))[has_gnss],
                            "north_m": (n[k1] + noise(gnss_sigma_m, k1.size))[has_gnss],
                            "sigma_m": np.full(has_gnss.sum(), max(gnss_sigma_m, 1e-3))})
    has_rsu = np.ones(tg.size, dtype=bool) if rsu_all_along else (tg >= third) & (tg < 2 * third)
    rsu = Channel("rsu", {"t_s": tg[has_rsu], "rsu_id": np.zeros(has_rsu.sum()),
                          "east_m": (e[k1] + noise(rsu_sigma_m, k1.size))[has_rsu],
                          "north_m": (n[k1] + noise(rsu_sigma_m, k1.size))[has_rsu],
                          "sigma_m": np.full(has_rsu.sum(), max(rsu_sigma_m, 1e-3))})
    truth = Channel("truth", {"t_s": t, "east_m": e, "north_m": n, "v_east_mps": speed_mps * np.cos(yaw),
                              "v_north_mps": speed_mps * np.sin(yaw), "yaw_rad": yaw})
    windows = (Window("zone:open", 0, third), Window("zone:tunnel", third, 2 * third), Window("zone:street", 2 * third, duration_s))
    return Drive("urban", {"imu": imu, "wheel": wheel, "gnss": gnss, "rsu": rsu, "truth": truth},
                 rsus=RsuMap([0], [0.0], [0.0]), windows=windows)


def errors(est, drive, start_s=0.0, end_s=np.inf):
    tr = drive.truth
    d = np.hypot(np.interp(est.t_s, tr.t_s, tr.east_m) - est.east_m, np.interp(est.t_s, tr.t_s, tr.north_m) - est.north_m)
    return d[(est.t_s >= start_s) & (est.t_s <= end_s)]


def drms2(err):
    return 2.0 * float(np.sqrt(np.mean(err**2)))


def test_zero_error_on_noiseless_data():
    drive = make_drive(duration_s=30.0, gnss_sigma_m=0.0, rsu_sigma_m=0.0, sensor_noise=False, gnss_bias=(0, 0, 0.0),
                       yaw_rate_radps=0.0)
    est = FederatedKf().run(drive)
    assert len(est) > 250
    assert errors(est, drive).max() < 1e-2


def test_isolates_a_biased_gnss_stream_and_restores_it():
    drive = make_drive(duration_s=90.0, gnss_bias=(30.0, 50.0, 15.0), rsu_all_along=True, seed=2)
    est = FederatedKf().run(drive)
    spans = est.diagnostics["subsystems"]["gnss"]["isolations"]
    inconsistent = [s for s in spans if s[2] == "inconsistent"]
    assert inconsistent, spans
    start, end, _ = inconsistent[0]
    assert 30.0 <= start < 36.0 and 50.0 <= end < 56.0
    assert errors(est, drive, 30.0, 56.0).max() < 4.0
    # without fault detection the bias leaks into the fused track
    loose = FederatedKf(Liu2016Config(consistency_probability=1.0)).run(drive)
    assert errors(loose, drive, 35.0, 50.0).mean() > 2 * errors(est, drive, 35.0, 50.0).mean()


def test_zones_isolate_the_missing_subsystem_and_beat_single_subsystems():
    drive = make_drive(duration_s=120.0, yaw_rate_radps=0.01, seed=3)
    fkf = FederatedKf().run(drive)
    diag = fkf.diagnostics["subsystems"]
    assert any(s[2] == "no data" and s[0] < 10 for s in diag["rsu"]["isolations"])  # no RSU in the open
    assert any(s[2] == "no data" and 40 < s[0] < 50 for s in diag["gnss"]["isolations"])  # GNSS blocked in the tunnel
    singles = {s: FederatedKf(Liu2016Config(subsystems=(s,), coast=False)).run(drive) for s in ("rsu", "gnss", "dr")}
    for w in drive.windows:
        ours = drms2(errors(fkf, drive, w.start_s + 5, w.end_s))
        for name, est in singles.items():
            theirs = errors(est, drive, w.start_s + 5, w.end_s)
            if theirs.size > 50:  # the subsystem works in this zone
                assert ours < drms2(theirs), (w.label, name)


def test_config_and_drive_errors():
    with pytest.raises(ConfigError):
        Liu2016Config(subsystems=("radar",))
    drive = make_drive(duration_s=10.0)
    no_fixes = drive.replace(channels={k: v for k, v in drive.channels.items() if k not in ("gnss", "rsu")})
    with pytest.raises(MissingChannelError):
        FederatedKf().run(no_fixes)


def test_fast_run_equals_the_process_loop():
    from graphpos.estimator import Estimator

    drive = make_drive(duration_s=30.0, gnss_bias=(10.0, 20.0, 15.0), rsu_all_along=True, seed=5)
    fast = FederatedKf().run(drive)
    loop = Estimator.run(FederatedKf(), drive)
    np.testing.assert_array_equal(fast.t_s, loop.t_s)
    np.testing.assert_allclose(fast.position, loop.position, rtol=0, atol=1e-12)
    assert fast.diagnostics == loop.diagnostics


# -- simulated urban-rsu-gnss drives (liu2016 §3) ---------------------------------

def test_urban_zones_isolation_and_single_subsystems():
    """Over seeds 0-2 (per-zone 2DRMS averaged): fkf beats every single
    subsystem where that subsystem works, and meets liu2016's 2DRMS <= 2 m
    in the open and in the tunnel."""
    from eval.metrics import evaluate_estimate
    from graphpos.sim import simulate

    zones = ("zone:open", "zone:tunnel", "zone:street")
    ours, theirs = [], {name: [] for name in ("rsu", "gnss", "dr")}
    for seed in range(3):
        drive = simulate("urban-rsu-gnss", seed=seed)
        fkf = FederatedKf().run(drive)
        iso = fkf.diagnostics["subsystems"]
        tunnel = drive.window("zone:tunnel")[0]
        # GNSS blocked in the tunnel, no RSU in the open
        assert any(r == "no data" and tunnel.start_s <= a <= tunnel.start_s + 5 for a, _, r in iso["gnss"]["isolations"])
        assert any(r == "no data" and a <= tunnel.start_s for a, _, r in iso["rsu"]["isolations"])
        w = evaluate_estimate(drive, fkf)["windows"]
        ours.append([w[z]["position"]["drms2_m"] for z in zones])
        for name in theirs:
            w = evaluate_estimate(drive, FederatedKf(Liu2016Config(subsystems=(name,), coast=False)).run(drive))["windows"]
            # only where the subsystem works (gives positions for 10 s or more)
            theirs[name].append([w[z]["position"]["drms2_m"] if w[z]["position"]["n"] >= 100 else np.nan for z in zones])
    ours = np.mean(ours, axis=0)
    for name, values in theirs.items():
        values = np.array(values)
        for k, zone in enumerate(zones):
            if np.isfinite(values[:, k]).all():
                assert ours[k] < values[:, k].mean(), (name, zone)
    assert ours[0] <= 2.0 and ours[1] <= 2.0, ours


def test_urban_gnss_jump_is_isolated_and_restored():
    """A 20 m GNSS jump (simulator fault) in the open, where GNSS is the only
    position source: isolated as inconsistent, restored after, error bounded."""
    from eval.metrics import evaluate_estimate
    from graphpos.sim import simulate

    drive = simulate("urban-rsu-gnss", seed=1, faults={"gnss_jump": {"start_s": 20.0, "duration_s": 10.0}})
    est = FederatedKf().run(drive)
    spans = [s for s in est.diagnostics["subsystems"]["gnss"]["isolations"] if s[2] == "inconsistent"]
    assert len(spans) == 1 and 20.0 <= spans[0][0] <= 24.0 and 30.0 <= spans[0][1] <= 35.0, spans
    fault = evaluate_estimate(drive, est)["windows"]["fault:gnss_jump"]["position"]
    unprotected = evaluate_estimate(drive, FederatedKf(Liu2016Config(consistency_probability=1.0)).run(drive))
    assert fault["max_m"] < 3.0 < 10.0 < unprotected["windows"]["fault:gnss_jump"]["position"]["max_m"]


def test_rsu_range_readings_are_used():
    """An RSU radio that reports ranges (no fix): LF1 takes them as range rows."""
    drive = make_drive(duration_s=60.0, seed=4)
    tr = drive.truth
    rsu_e = np.arange(-20.0, 400.0, 40.0)
    rsu_n = rsu_e * math.tan(0.2) + 6.0
    rng = np.random.default_rng(4)
    t, ids, ranges = [], [], []
    for k in np.arange(0, len(tr), 100):
        if 20.0 <= tr.t_s[k] < 40.0:  # the tunnel third
            d = np.hypot(rsu_e - tr.east_m[k], rsu_n - tr.north_m[k])
            for j in np.argsort(d)[:2]:
                t.append(tr.t_s[k]); ids.append(j); ranges.append(d[j] + rng.normal(0, 0.5))
    rsu = Channel("rsu", {"t_s": t, "rsu_id": ids, "range_m": ranges, "sigma_m": np.full(len(t), 0.5)})
    ranged = drive.replace(channels={**drive.channels, "rsu": rsu}, rsus=RsuMap(np.arange(rsu_e.size), rsu_e, rsu_n))
    with_ranges = FederatedKf().run(ranged)
    without = FederatedKf(Liu2016Config(subsystems=("gnss", "dr"))).run(ranged)
    assert with_ranges.diagnostics["subsystems"]["rsu"]["tested"] == len(t)
    assert drms2(errors(with_ranges, ranged, 25.0, 40.0)) < drms2(errors(without, ranged, 25.0, 40.0))
