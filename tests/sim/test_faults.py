"""Fault injection: each fault does what it says, only there, labelled, seeded, composable."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.errors import ConfigError
from graphpos.sim import SCENARIOS, simulate
from graphpos.sim.faults import FAULTS

EPISODE = {"start_s": 20.0, "duration_s": 15.0}


def inside(channel, window):
    return window.contains(channel.t_s)


#: The default episode (30 % into the drive) finds no GNSS fix: the paper drives have them on the
#: approach only, urban-rsu-gnss and long-tunnel lose them in the tunnel; urban-rsu-gnss has no RFID.
NOTHING_TO_ACT_ON = {(sc, kind) for sc in ("paper-straight", "paper-comprehensive", "paper-imm", "urban-rsu-gnss", "long-tunnel")
                     for kind in ("gnss_jump", "gnss_multipath")} | {("urban-rsu-gnss", "dead_tags"), ("urban-rsu-gnss", "clock_offset")}


@pytest.mark.parametrize("scenario", list(SCENARIOS))
@pytest.mark.parametrize("kind", list(FAULTS))
def test_every_fault_on_every_scenario(scenario, kind):
    if (scenario, kind) in NOTHING_TO_ACT_ON:  # refused: its window would label a clean span as a fault
        with pytest.raises(ConfigError, match=f"fault '{kind}'.* has nothing to act on"):
            simulate(scenario, seed=3, faults={kind: {}})
        return
    drive = simulate(scenario, seed=3, faults={kind: {}})
    windows = drive.window(f"fault:{kind}")
    assert len(windows) == 1
    assert 0.0 <= windows[0].start_s <= windows[0].end_s <= drive.end_s
    assert drive.params["faults"][kind][0].keys() >= FAULTS[kind].keys()
    assert drive.truth == simulate(scenario, seed=3).truth


def test_dead_tags_never_heard():
    clean = simulate("paper-straight", seed=4)
    drive = simulate("paper-straight", seed=4, faults={"dead_tags": {"fraction": 0.25}})
    dead = drive.params["faults"]["dead_tags"][0]["dead_tag_ids"]
    assert len(dead) == round(0.25 * 42)
    assert not np.isin(drive.rfid.tag_id, dead).any()
    assert np.isin(clean.rfid.tag_id, dead).any()
    assert drive.rfid == clean.rfid.select(~np.isin(clean.rfid.tag_id, dead))


@pytest.mark.parametrize("scenario,channel", [("paper-straight", "rfid"), ("urban-rsu-gnss", "rsu")])
def test_blackout_silences_readers_only_there(scenario, channel):
    start = 60.0 if scenario == "urban-rsu-gnss" else 20.0
    clean = simulate(scenario, seed=5)
    drive = simulate(scenario, seed=5, faults={"rfid_blackout": {"start_s": start, "duration_s": 30.0}})
    (w,) = drive.window("fault:rfid_blackout")
    ch, ref = drive.channels[channel], clean.channels[channel]
    assert not inside(ch, w).any() and inside(ref, w).any()
    assert ch == ref.select(~inside(ref, w))
    assert drive.imu == clean.imu


def test_nlos_burst_weakens_rss_inside_only():
    clean = simulate("paper-straight", seed=6)
    drive = simulate("paper-straight", seed=6, faults={"nlos_burst": {**EPISODE, "probability": 1.0, "sigma_db": 0.0}})
    (w,) = drive.window("fault:nlos_burst")
    m = inside(drive.rfid, w)
    diff = drive.rfid.rss - clean.rfid.rss
    assert np.all(diff[~m] == 0)
    assert np.median(diff[m]) == pytest.approx(-15 * 3.0, abs=1.0)  # bias_db x units_per_db of the tunnel law


def test_nlos_burst_biases_rsu_ranges():
    clean = simulate("urban-rsu-gnss", seed=6)
    drive = simulate("urban-rsu-gnss", seed=6, faults={"nlos_burst": {"start_s": 60.0, "duration_s": 20.0, "probability": 1.0}})
    (w,) = drive.window("fault:nlos_burst")
    m = inside(drive.rsu, w)
    extra = drive.rsu.range_m - clean.rsu.range_m
    assert np.all(extra[~m] == 0) and np.all(extra[m] > 0) and np.mean(extra[m]) == pytest.approx(10.0, rel=0.3)


def test_wheel_slip_and_compass_disturbance():
    clean = simulate("paper-comprehensive", seed=7)
    drive = simulate("paper-comprehensive", seed=7, faults={"wheel_slip": {**EPISODE, "slip": 0.3},
                                                             "compass_disturbance": {**EPISODE, "offset_deg": 20.0}})
    (w,) = drive.window("fault:wheel_slip")
    m = inside(drive.wheel, w)
    assert np.allclose(drive.wheel.speed_mps[m], 1.3 * clean.wheel.speed_mps[m])
    assert np.array_equal(drive.wheel.speed_mps[~m], clean.wheel.speed_mps[~m])
    m = inside(drive.compass, drive.window("fault:compass_disturbance")[0])
    delta = np.angle(np.exp(1j * (drive.compass.yaw_rad - clean.compass.yaw_rad)))
    assert np.allclose(delta[m], np.deg2rad(20.0)) and np.allclose(delta[~m], 0.0)


def test_gnss_jump_and_multipath():
    clean = simulate("urban-rsu-gnss", seed=8)
    drive = simulate("urban-rsu-gnss", seed=8, faults={"gnss_jump": {"start_s": 10.0, "duration_s": 10.0, "jump_m": 20.0},
                                                        "gnss_multipath": {"start_s": 140.0, "duration_s": 30.0}})
    g, c = drive.gnss, clean.gnss
    shift = np.hypot(g.east_m - c.east_m, g.north_m - c.north_m)
    jump = inside(g, drive.window("fault:gnss_jump")[0])
    multi = inside(g, drive.window("fault:gnss_multipath")[0])
    assert np.allclose(shift[jump], 20.0)
    assert np.all(shift[~jump & ~multi] == 0)
    assert np.sqrt(np.mean(shift[multi] ** 2)) > 5.0
    assert np.array_equal(g.sigma_m, c.sigma_m)


def test_clock_offset_shifts_one_channel():
    clean = simulate("paper-straight", seed=9, rfid_latency_s=0.3)
    drive = simulate("paper-straight", seed=9, rfid_latency_s=0.3, faults={"clock_offset": {"channel": "rfid", "offset_s": -0.25}})
    assert np.allclose(drive.rfid.t_s, clean.rfid.t_s - 0.25)
    assert np.allclose(drive.rfid.arrival_s - drive.rfid.t_s, 0.3)
    assert drive.imu == clean.imu


def test_dropped_duplicated_and_late():
    clean = simulate("paper-straight", seed=10, duration_s=300)
    drive = simulate("paper-straight", seed=10, duration_s=300, faults={
        "dropped_samples": {"channels": ["imu"], "fraction": 0.1},
        "duplicated_samples": {"channels": ["wheel"], "fraction": 0.05},
        "late_readings": {"fraction": 0.3, "min_s": 0.5, "max_s": 2.0},
    })
    assert len(drive.imu) / len(clean.imu) == pytest.approx(0.9, abs=0.01)
    assert np.isin(drive.imu.t_s, clean.imu.t_s).all()
    assert len(drive.wheel) / len(clean.wheel) == pytest.approx(1.05, abs=0.01)
    assert (np.diff(drive.wheel.t_s) == 0).sum() == len(drive.wheel) - len(clean.wheel)
    delay = drive.rfid.arrival_s - drive.rfid.t_s
    late = delay > 0
    assert late.mean() == pytest.approx(0.3, abs=0.06)
    assert delay[late].min() >= 0.5 and delay.max() <= 2.0
    assert drive.compass == clean.compass


def test_faults_compose_independently():
    alone = simulate("paper-straight", seed=11, faults={"dead_tags": {"fraction": 0.2}})
    both = simulate("paper-straight", seed=11, faults={"rfid_blackout": EPISODE, "dead_tags": {"fraction": 0.2}})
    assert both.params["faults"]["dead_tags"] == alone.params["faults"]["dead_tags"]
    (w,) = both.window("fault:rfid_blackout")
    assert both.rfid == alone.rfid.select(~inside(alone.rfid, w))
    again = simulate("paper-straight", seed=11, faults={"rfid_blackout": EPISODE, "dead_tags": {"fraction": 0.2}})
    assert again.rfid == both.rfid


def test_several_episodes_of_one_kind():
    drive = simulate("paper-straight", seed=12, faults={"rfid_blackout": [{"start_s": 10, "duration_s": 5}, {"start_s": 40, "duration_s": 10}]})
    spans = [(w.start_s, w.end_s) for w in drive.window("fault:rfid_blackout")]
    assert spans == [(10.0, 15.0), (40.0, 50.0)]
    for w in drive.window("fault:rfid_blackout"):
        assert not inside(drive.rfid, w).any()


@pytest.mark.parametrize(
    "faults,words",
    [
        ({"bogus": {}}, ["unknown fault", "dead_tags"]),
        ({"dead_tags": {"fraction": 2}}, ["fraction", "[0, 1]"]),
        ({"dead_tags": {"share": 0.1}}, ["share", "fraction"]),
        ({"wheel_slip": 0.3}, ["table"]),
        ({"clock_offset": {"channel": "truth"}}, ["channel"]),
        ({"dropped_samples": {"channels": ["imu", "lidar"]}}, ["channels"]),
        ({"late_readings": {"min_s": 3, "max_s": 1}}, ["min_s"]),
        ({"rfid_blackout": {"duration_s": -1}}, ["duration_s"]),
        ({"gnss_jump": {"jump_m": "far"}}, ["jump_m"]),
        ({"rfid_blackout": {"start_s": 500}}, ["start_s must be within the drive (0 to 76 s), got 500"]),
        ({"rfid_blackout": {"start_s": -5}}, ["start_s must be within the drive"]),
        ({"rfid_blackout": {"duration_s": 0}}, ["duration_s must be positive"]),
        ({"gnss_jump": {"start_s": 30}}, ["has nothing to act on", "it has gnss at 0.0-5.0 s"]),
    ],
)
def test_bad_faults(faults, words):
    with pytest.raises(ConfigError) as info:
        simulate("paper-straight", seed=0, faults=faults)
    for word in words:
        assert word in str(info.value)
