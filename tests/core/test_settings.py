"""Estimator settings as text (``--set [NAME.]KEY=VALUE``): routing, types, errors."""

from __future__ import annotations

import pytest

from graphpos.errors import ConfigError
from graphpos.registry import estimator_classes, make_estimator
from graphpos.settings import apply_settings, as_text, parse_settings, setting_names


def defaults(*names: str) -> dict:
    classes = estimator_classes()
    return {n: classes[n].default_config() for n in names}


def test_unqualified_key_goes_to_every_estimator_that_has_it():
    names = ["fusion-ekf", "graph-isam2", "graph-fixed-lag"]
    out = parse_settings(["fixed_lag_s=20", "fusion-ekf.wheel_sigma_mps=2", "graph-isam2.final=true"], names, defaults(*names))
    assert out == {
        "graph-isam2": {"fixed_lag_s": "20", "final": "true"},
        "graph-fixed-lag": {"fixed_lag_s": "20"},
        "fusion-ekf": {"wheel_sigma_mps": "2"},
    }


@pytest.mark.parametrize(
    "item, message",
    [
        ("fixed_lag_s", "not of the form"),
        ("=3", "not of the form"),
        ("fixed_lag_s=3", "no selected estimator"),
        ("graph-isam2.final=true", "not selected"),
        ("fusion-ekf.no_such=1", "fusion-ekf has no setting 'no_such'"),
    ],
)
def test_parse_errors_say_what_is_wrong(item, message):
    with pytest.raises(ConfigError, match=message):
        parse_settings([item], ["fusion-ekf"], defaults("fusion-ekf"))


def test_values_take_the_field_type():
    graph = defaults("graph-isam2")["graph-isam2"]
    cfg = apply_settings(graph, {"final": "yes", "batch_max_iterations": "7", "fixed_lag_s": "12.5", "robust_loss": "huber",
                                 "range_scale_bounds": "0.9, 1.1"}, "graph-isam2")
    assert cfg.final is True and cfg.batch_max_iterations == 7 and cfg.fixed_lag_s == 12.5
    assert cfg.robust_loss == "huber" and cfg.range_scale_bounds == (0.9, 1.1)
    fusion = defaults("fusion-ekf")["fusion-ekf"]
    assert apply_settings(fusion, {"lateral_velocity_sigma_mps": "None"}, "fusion-ekf").lateral_velocity_sigma_mps is None
    imm = defaults("imm-stekf")["imm-stekf"]
    nested = apply_settings(imm, {"fading.forgetting_factor": "0.9", "markov": "0.8,0.2;0.3,0.7"}, "imm-stekf")
    assert nested.fading.forgetting_factor == 0.9
    assert nested.markov == ((0.8, 0.2), (0.3, 0.7))
    assert defaults("imm-stekf")["imm-stekf"].fading.forgetting_factor != 0.9  # the default is untouched


@pytest.mark.parametrize(
    "name, key, text, message",
    [
        ("graph-isam2", "final", "maybe", "expected true or false"),
        ("graph-isam2", "batch_max_iterations", "2.5", "whole number"),
        ("graph-isam2", "fixed_lag_s", "nan", "finite"),
        ("graph-isam2", "range_scale_bounds", "1,2,3", "2 comma-separated"),
        ("graph-isam2", "robust_loss", "l1", "graph-isam2: robust_loss must be one of"),
        ("graph-isam2", "fixed_lag_s", "1", "must exceed max_delay_s"),
        ("fusion-ekf", "wheel_sigma_mps", "-1", "wheel_sigma_mps must be a positive"),
        ("fusion-ekf", "range_gate_probability", "1.5", r"\(0, 1\]"),
        ("fukf", "beta_few_tags", "0.5,0.6", "sum to 1"),
        ("rfid-ekf", "update_iterations", "0", "at least 1"),
        ("multilateration", "min_tags", "2", "min_tags >= 3"),
        ("imm-stekf", "ca_accel_noise_mps2", "0", "ca_accel_noise_mps2 must be a positive"),
        ("imm-stekf", "fading.forgetting_factor", "1.5", "forgetting_factor must lie in"),
        ("imm-stekf", "lms.consistency_probability", "2", "consistency_probability must lie in"),
        ("fkf", "odometer_sigma_mps", "-0.3", "odometer_sigma_mps must be a positive"),
        # 1 MHz on a 30 s drive ran for minutes towards 70 GB of rows
        ("fusion-ekf", "output_rate_hz", "1e6", "output_rate_hz must be at most 1000 Hz"),
        ("imm-stekf", "output_rate_hz", "2000", "output_rate_hz must be at most 1000 Hz"),
        ("fkf", "output_rate_hz", "1001", "output_rate_hz must be at most 1000 Hz"),
        ("graph-isam2", "keyframe_rate_hz", "5000", "keyframe_rate_hz must be at most 1000 Hz"),
    ],
)
def test_bad_values_are_config_errors(name, key, text, message):
    with pytest.raises(ConfigError, match=message):
        make_estimator(name, settings={key: text})


def test_python_values_are_taken_as_their_text():
    """From Python, a setting may be given as a value rather than text: the same config as the text gives,
    and a value of the wrong kind is a ConfigError (it was an AttributeError)."""
    graph = defaults("graph-isam2")["graph-isam2"]
    given = {"learn_online": False, "batch_max_iterations": 7, "fixed_lag_s": 12.5, "range_scale_bounds": (0.9, 1.1)}
    assert apply_settings(graph, given, "graph-isam2") == apply_settings(graph, {k: as_text(v) for k, v in given.items()}, "graph-isam2")
    imm = defaults("imm-stekf")["imm-stekf"]
    assert apply_settings(imm, {"markov": ((0.8, 0.2), (0.3, 0.7))}, "imm-stekf").markov == ((0.8, 0.2), (0.3, 0.7))
    with pytest.raises(ConfigError, match="expected true or false"):
        make_estimator("graph-isam2", settings={"learn_online": 3})


def _field(config, path: str):
    for part in path.split("."):
        config = getattr(config, part)
    return config


@pytest.mark.parametrize("name", list(estimator_classes()))
def test_every_setting_round_trips_through_text(name):
    """Each default, written as text and read back, gives the same config."""
    config = estimator_classes()[name].default_config()
    assert setting_names(config)
    for key in setting_names(config):
        value = _field(config, key)
        again = apply_settings(config, {key: as_text(value)}, name)
        assert again == config, key
        assert type(_field(again, key)) is type(value), key
