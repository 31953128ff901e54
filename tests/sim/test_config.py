"""Parameters: overrides, TOML config files and the errors for bad ones."""

from __future__ import annotations

import numpy as np
import pytest

from graphpos.errors import ConfigError, FileFormatError
from graphpos.sim import SCENARIOS, default_params, load_config, simulate


def test_every_scenario_has_full_defaults():
    for name in SCENARIOS:
        p = default_params(name)
        assert p["rss_environment"] == "tunnel"
        assert p["imu"]["accel_sigma_mps2"] == 0.1 and p["imu"]["gyro_sigma_dps"] == 0.2  # song2016 §6
        assert p["imu"]["rate_hz"] == 100.0 and p["wheel"]["rate_hz"] == 100.0 and p["compass"]["rate_hz"] == 10.0
        if "rfid" in p:
            assert p["rfid"]["rate_hz"] == 1.0
    assert default_params("urban-rsu-gnss")["rsu"]["count"] == 7  # liu2016 §3
    assert default_params("urban-rsu-gnss")["motion"]["speed_mps"] == pytest.approx(20 / 3.6)
    assert default_params("paper-imm")["route"]["width_m"] == 7.5  # song2014 §5


@pytest.mark.parametrize(
    "kwargs,words",
    [
        ({"scenario": "nope"}, ["unknown scenario", "paper-straight"]),
        ({"scenario": "paper-straight", "pattern": "lane-change-curve"}, ["no motion pattern", "accel, decel, constant"]),
        ({"scenario": "paper-straight", "overrides": {"imu": {"gyro_sigma": 1}}}, ["imu.gyro_sigma", "gyro_sigma_dps"]),
        ({"scenario": "paper-straight", "overrides": {"nonsense": 1}}, ["nonsense", "imu"]),
        ({"scenario": "paper-straight", "overrides": {"imu": 3}}, ["section"]),
        ({"scenario": "paper-straight", "overrides": {"imu": {"rate_hz": "fast"}}}, ["imu.rate_hz", "number"]),
        ({"scenario": "paper-straight", "overrides": {"imu": {"rate_hz": 0}}}, ["imu.rate_hz", "(0, 1000]"]),
        ({"scenario": "paper-straight", "overrides": {"rfid": {"outlier_probability": 2}}}, ["[0, 1]"]),
        ({"scenario": "paper-straight", "overrides": {"rss_environment": "space"}}, ["rss_environment", "tunnel"]),
        ({"scenario": "urban-rsu-gnss", "overrides": {"tags": {"spacing_m": 3}}}, ["unknown parameter 'tags'"]),
        ({"scenario": "paper-straight", "duration_s": -1}, ["duration"]),
        ({"scenario": "paper-straight", "duration_s": float("nan")}, ["duration"]),
        ({"scenario": "paper-straight", "duration_s": 1e9}, ["duration", "longer"]),
        ({"scenario": "paper-straight", "overrides": {"imu": {"rate_hz": 1e7}}}, ["imu.rate_hz", "Hz"]),
        ({"scenario": "paper-straight", "seed": -2}, ["seed"]),
        ({"scenario": "paper-straight", "seed": 1.5}, ["seed"]),
        ({"scenario": "paper-straight", "rfid_latency_s": -1}, ["latency"]),
        ({"scenario": "paper-straight", "rfid_latency_s": (2, 1)}, ["latency"]),
        ({"scenario": "paper-comprehensive", "pattern": "lane-change-curve", "overrides": {"motion": {"lane_change_length_m": 500}}},
         ["lane_change_length_m"]),
        ({"scenario": "paper-straight", "overrides": {"motion": {"speed_low_mps": 5.0}}}, ["speed_low_mps"]),
        ({"scenario": "paper-straight", "overrides": {"gnss": {"tail_dof": 1}}}, ["unknown parameter 'gnss'"]),
        ({"scenario": "paper-straight", "overrides": {"faults": {"dead_tags": {}}}}, ["simulate(faults=...)"]),
        ({"scenario": "urban-rsu-gnss", "overrides": {"gnss": {"zones": {"street": {"tail_dof": 1.5}}}}}, ["tail_dof"]),
    ],
)
def test_bad_arguments_raise_config_error(kwargs, words):
    with pytest.raises(ConfigError) as info:
        simulate(**kwargs)
    for word in words:
        assert word in str(info.value)


def test_overrides_take_effect():
    d = simulate("paper-straight", seed=0, overrides={"imu": {"rate_hz": 50}, "rfid": {"rate_hz": 2.0}, "route": {"tunnel_straight_m": 60.0}})
    assert np.allclose(np.diff(d.imu.t_s), 0.02)
    assert np.allclose(np.diff(np.unique(d.rfid.t_s)).min(), 0.5)
    assert len(d.tags) == 22 and d.tags.layout("optimized").size == 8


def test_load_config_round_trip(tmp_path):
    f = tmp_path / "sim.toml"
    f.write_text('rss_environment = "outdoor"\n[imu]\ngyro_sigma_dps = 0.3\n[gnss.zones.street]\nbias_m = 4.0\n')
    cfg = load_config(f)
    assert cfg == {"rss_environment": "outdoor", "imu": {"gyro_sigma_dps": 0.3}, "gnss": {"zones": {"street": {"bias_m": 4.0}}}}
    d = simulate("urban-rsu-gnss", seed=0, duration_s=10, overrides=cfg)
    assert d.params["imu"]["gyro_sigma_dps"] == 0.3 and d.params["gnss"]["zones"]["street"]["bias_m"] == 4.0
    assert d.params["rss_environment"] == "outdoor"


@pytest.mark.parametrize("content", [b"[imu\n", b"x = = 1\n", b"\xff\xfe\x00"])
def test_load_config_bad_files(tmp_path, content):
    f = tmp_path / "bad.toml"
    f.write_bytes(content)
    with pytest.raises(FileFormatError) as info:
        load_config(f)
    assert str(f) in str(info.value)


def test_load_config_missing_file(tmp_path):
    with pytest.raises(FileFormatError):
        load_config(tmp_path / "absent.toml")
    with pytest.raises(FileFormatError):
        load_config(tmp_path)  # a folder


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_default_params_dump_as_toml_and_read_back(name, tmp_path, capsys):
    from graphpos.cli import main

    assert main(["scenarios", "--params", name]) == 0
    f = tmp_path / "defaults.toml"
    f.write_text(capsys.readouterr().out)
    assert load_config(f) == default_params(name)
    # a dumped file is a valid --config: the same drive as the defaults
    assert simulate(name, seed=1, duration_s=20, overrides=load_config(f)).imu == simulate(name, seed=1, duration_s=20).imu


def _leaves(d, path=()):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _leaves(v, path + (k,))
        elif not isinstance(v, str):
            yield path + (k,), v


def _nested(path, value):
    for k in reversed(path):
        value = {k: value}
    return value


def _try_extremes(name, values):
    from graphpos.errors import GraphposError

    for path, default in _leaves(default_params(name)):
        for x in values:
            x = int(x) if isinstance(default, int) else x
            try:
                simulate(name, seed=0, duration_s=20, overrides=_nested(path, x))
            except GraphposError:
                pass  # refused with a clear message: fine; anything else fails the test


def test_extreme_values_build_or_are_refused():
    """Every parameter at 0 and 1e6: a drive or a clear error, never a crash."""
    _try_extremes("paper-comprehensive", (0, 1e6))


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_extreme_values_every_scenario(name):
    _try_extremes(name, (0, 1e-9, 0.5, 1e6))
