"""Each scenario: channels at their rates, tags and layouts, windows, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphpos.drive import Drive
from graphpos.sim import SCENARIOS, default_params, simulate
from graphpos.sim.scenarios import CURVE_PATTERNS, STRAIGHT_PATTERNS

PAPER = ("paper-straight", "paper-comprehensive", "paper-imm")


def distinct_rate_hz(t: np.ndarray) -> float:
    """Distinct timestamps per second (as `graphpos info` counts them)."""
    u = np.unique(t)
    return (u.size - 1) / (u[-1] - u[0])


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_channels_at_configured_rates(name):
    drive = simulate(name, seed=1)
    params = default_params(name)
    expected = {"truth": params["truth"]["rate_hz"], "imu": params["imu"]["rate_hz"], "wheel": params["wheel"]["rate_hz"],
                "compass": params["compass"]["rate_hz"]}
    for channel, rate in expected.items():
        assert distinct_rate_hz(drive.channels[channel].t_s) == pytest.approx(rate, rel=1e-9), channel
    if "rfid" in params:
        t = drive.rfid.t_s
        # reads at k / rate; a read may hear no tag (approach roads), never off the grid
        k = t * params["rfid"]["rate_hz"]
        assert np.allclose(k, np.round(k))
        inside = drive.window("in_tunnel")[0]
        reads = np.unique(t[(t >= inside.start_s) & (t <= inside.end_s)])
        assert reads.size >= 0.95 * (inside.end_s - inside.start_s) * params["rfid"]["rate_hz"]
    for channel in ("gnss", "rsu"):
        if channel in params:
            t = drive.channels[channel].t_s
            assert np.allclose(np.diff(np.unique(t)).min(), 1.0 / params[channel]["rate_hz"])
    assert drive.duration_s == pytest.approx(SCENARIOS[name].default_duration_s, abs=0.01)


@pytest.mark.parametrize("name", PAPER)
def test_paper_tag_counts(name):
    drive = simulate(name, seed=0)
    assert len(drive.tags) == 42
    assert drive.tags.layout("dense").size == 42
    assert drive.tags.layout("optimized").size == 16
    opt = drive.tags.layout("optimized")
    # four groups of four: two per wall, 6 m apart
    groups = drive.tags.group[drive.tags.index_of(opt)]
    assert sorted(np.bincount(groups)) == [4, 4, 4, 4]
    for g in range(4):
        members = drive.tags.index_of(opt[groups == g])
        assert sorted(drive.tags.wall_side[members]) == [-1, -1, 1, 1]
    assert (drive.tags.group[drive.tags.index_of(np.setdiff1d(drive.tags.tag_id, opt))] == -1).all()
    for name_, n_groups in (("groups-60m", 2), ("groups-90m", 2), ("groups-120m", 1)):
        ids = drive.tags.layout(name_)
        assert ids.size == 4 * n_groups
        assert np.isin(ids, drive.tags.tag_id).all()


def test_tags_on_both_walls_every_6m():
    drive = simulate("paper-straight", seed=0)
    tags = drive.tags
    width = default_params("paper-straight")["route"]["width_m"]
    for side in (-1, 1):
        m = tags.wall_side == side
        assert m.sum() == 21
        assert np.allclose(np.diff(np.sort(tags.east_m[m])), 6.0)
        assert np.allclose(tags.north_m[m], side * width / 2)


def test_long_tunnel_layouts():
    drive = simulate("long-tunnel", seed=0, duration_s=10.0)
    lay = {k: v.size for k, v in drive.tags.layouts.items()}
    # 3000 m: 501 positions on two walls; groups every 30 m that fit: 100
    assert lay == {"dense": 1002, "optimized": 400, "groups-60m": 200, "groups-90m": 136, "groups-120m": 100}


def test_urban_has_rsus_and_gnss_by_zone():
    drive = simulate("urban-rsu-gnss", seed=2)
    assert len(drive.rsus) == 7
    assert not drive.has("rfid")
    rsu = drive.rsu
    assert np.isfinite(rsu.east_m).all() and np.isfinite(rsu.range_m).all()
    (tunnel,) = drive.window("zone:tunnel")
    assert ((rsu.t_s >= tunnel.start_s) & (rsu.t_s <= tunnel.end_s)).all()
    g = drive.gnss.t_s
    assert not ((g > tunnel.start_s) & (g < tunnel.end_s)).any()
    for zone in ("zone:open", "zone:street"):
        (w,) = drive.window(zone)
        n = ((g >= w.start_s) & (g <= w.end_s)).sum()
        assert n >= (w.end_s - w.start_s) - 1


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_windows_partition_the_drive(name):
    realised = simulate(name, seed=0, duration_s=1.0).params["realised"]
    # out, turn, back, turn, and most of the next pass out
    drive = simulate(name, seed=0, duration_s=realised["lap_duration_s"] + 0.9 * realised["pass_duration_s"])
    zones = sorted((w for w in drive.windows if w.label.startswith("zone:")), key=lambda w: w.start_s)
    assert zones[0].start_s == 0.0 and zones[-1].end_s == pytest.approx(drive.end_s)
    for a, b in zip(zones, zones[1:]):
        assert b.start_s - a.end_s == pytest.approx(0.01)  # consecutive truth samples
    tunnels = drive.window("in_tunnel")
    assert len(tunnels) == 3  # out, back, out again
    assert [(w.start_s, w.end_s) for w in tunnels] == [(w.start_s, w.end_s) for w in drive.window("zone:tunnel")]
    assert len(drive.window("turnaround")) == 2
    for w in drive.windows:
        assert 0.0 <= w.start_s <= w.end_s <= drive.end_s
    if name in ("paper-comprehensive", "paper-imm"):
        assert len(drive.window("curve")) == 3
        assert drive.window("straight")


def test_paper_straight_timing():
    """song2016 §6.3.2: a 76 s test, inside the tunnel from about 7 s to 68 s."""
    drive = simulate("paper-straight", seed=0)
    (w,) = drive.window("in_tunnel")
    assert drive.duration_s == pytest.approx(76.0, abs=1.0)
    assert w.start_s == pytest.approx(7.0, abs=1.0) and w.end_s == pytest.approx(67.5, abs=1.5)
    speed = np.hypot(drive.truth.v_east_mps, drive.truth.v_north_mps)
    assert speed.mean() == pytest.approx(2.0, rel=0.05)


def test_no_tag_heard_far_out_on_the_approach():
    drive = simulate("paper-straight", seed=0)
    t = drive.rfid.t_s
    # the first 5 m of the 14 m approach are beyond the 9 m reach of the portal tags
    assert not (t < 2.0).any()


@pytest.mark.parametrize("name,patterns", [("paper-straight", STRAIGHT_PATTERNS), ("paper-comprehensive", CURVE_PATTERNS)])
def test_every_pattern_runs_and_differs(name, patterns):
    drives = {p: simulate(name, pattern=p, seed=0) for p in patterns}
    speeds = {p: np.hypot(d.truth.v_east_mps, d.truth.v_north_mps) for p, d in drives.items()}
    assert speeds["accel"][-1] > speeds["accel"][0] + 1.0
    assert speeds["decel"][-1] < speeds["decel"][0] - 1.0
    assert np.ptp(speeds["constant"]) < 1e-9
    if "lane-change-curve" in drives:
        for p in ("accel-variable", "decel-variable"):
            d = drives[p]
            (curve,) = d.window("curve")[:1] or [None]
            m = (d.truth.t_s >= curve.start_s) & (d.truth.t_s <= curve.end_s)
            assert np.ptp(d.truth.yaw_rate_radps[m]) > 0.01  # variable angular velocity in the curve
        for p in ("accel", "decel", "constant"):
            d = drives[p]
            curve = d.window("curve")[0]
            m = (d.truth.t_s >= curve.start_s + 1) & (d.truth.t_s <= curve.end_s - 1)
            assert np.ptp(d.truth.yaw_rate_radps[m]) < 1e-3  # constant angular velocity


def test_lane_changes_cross_one_lane():
    base = simulate("paper-comprehensive", pattern="constant", seed=0)
    for pattern, part in (("lane-change-straight", "straight"), ("lane-change-curve", "curve")):
        d = simulate("paper-comprehensive", pattern=pattern, seed=0)
        w = d.window(part)[0]
        m = w.contains(d.truth.t_s)
        # the S-curve of a lane change: lateral acceleration swings both ways
        # about the bend's steady value
        ay = d.truth.accel_y_mps2[m] - np.median(d.truth.accel_y_mps2[m])
        assert ay.max() > 0.005 and ay.min() < -0.005, pattern
        # after the pass the vehicle is one lane (3 m) left of the constant-speed track
        yaw = d.truth.yaw_rad[-1]
        rel_e = base.truth.east_m - d.truth.east_m[-1]
        rel_n = base.truth.north_m - d.truth.north_m[-1]
        along = np.cos(yaw) * rel_e + np.sin(yaw) * rel_n
        lateral = -np.sin(yaw) * rel_e + np.cos(yaw) * rel_n
        assert lateral[np.argmin(np.abs(along))] == pytest.approx(-3.0, abs=0.05), pattern


def test_deterministic_per_seed():
    a = simulate("paper-comprehensive", "lane-change-curve", seed=5, duration_s=200)
    b = simulate("paper-comprehensive", "lane-change-curve", seed=5, duration_s=200)
    c = simulate("paper-comprehensive", "lane-change-curve", seed=6, duration_s=200)
    for name in a.channels:
        assert a.channels[name] == b.channels[name]
    assert a.tags == b.tags and a.windows == b.windows and a.params == b.params
    assert a.truth == c.truth  # the trajectory does not depend on the seed
    assert not np.array_equal(a.imu.yaw_rate_radps, c.imu.yaw_rate_radps)
    assert not np.array_equal(a.rfid.rss, c.rfid.rss)


def test_params_record_everything():
    d = simulate("urban-rsu-gnss", pattern="accel", seed=3, duration_s=50, overrides={"imu": {"gyro_sigma_dps": 0.3}})
    p = json.loads(json.dumps(d.params))
    assert p["scenario"] == "urban-rsu-gnss" and p["pattern"] == "accel" and p["seed"] == 3
    assert p["rss_environment"] == "tunnel"
    assert p["imu"]["gyro_sigma_dps"] == 0.3
    assert p["duration_s"] == 50.0
    assert isinstance(d, Drive) and d.duration_s == pytest.approx(50.0)


def test_rfid_latency_sets_arrival():
    fixed = simulate("paper-straight", seed=0, rfid_latency_s=0.7)
    assert np.allclose(fixed.rfid.arrival_s - fixed.rfid.t_s, 0.7)
    ranged = simulate("paper-straight", seed=0, rfid_latency_s=(0.5, 2.0))
    delay = ranged.rfid.arrival_s - ranged.rfid.t_s
    assert delay.min() >= 0.5 and delay.max() <= 2.0 and np.ptp(delay) > 0.5
    # one delay per read: all tags of a read arrive together
    for t in np.unique(ranged.rfid.t_s)[:20]:
        assert np.ptp(delay[ranged.rfid.t_s == t]) == 0.0
    urban = simulate("urban-rsu-gnss", seed=0, rfid_latency_s=(0.5, 2.0))
    d = urban.rsu.arrival_s - urban.rsu.t_s
    assert d.min() >= 0.5 and d.max() <= 2.0
    # same readings as without latency
    plain = simulate("paper-straight", seed=0)
    assert np.array_equal(plain.rfid.rss, ranged.rfid.rss)
    assert np.array_equal(plain.rfid.arrival_s, plain.rfid.t_s)


def test_long_drive_goes_out_and_back(long_straight):
    truth = long_straight.truth
    assert long_straight.duration_s == pytest.approx(600.0)
    assert len(long_straight.window("in_tunnel")) >= 5  # 76 s passes, ~30 s U-turns
    # stays on the road: within the tunnel walls wherever it is in the tunnel
    width = long_straight.params["route"]["width_m"]
    for w in long_straight.window("in_tunnel"):
        m = w.contains(truth.t_s)
        assert np.abs(truth.north_m[m]).max() < width / 2
    speed = np.hypot(truth.v_east_mps, truth.v_north_mps)
    assert speed.min() > 0.5
