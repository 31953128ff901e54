"""Range-scale self-calibration (no truth used by the estimators) and Plaza1 accuracy."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SYNTHETIC_MODEL, position_errors, synthetic_drive

from graphpos.graph import ESTIMATORS
from graphpos.graph.calibration import calibrate_range_scale
from graphpos.graph.config import GraphConfig
from graphpos.ranging.model import LinearCalibration


def rms(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors**2)))


def test_scale_recovered_on_a_long_reading_radio():
    drive = synthetic_drive(40, seed=13, turn_radps=0.05, range_scale=1.07)
    config = GraphConfig(parameterisation="planar", **SYNTHETIC_MODEL)
    model = calibrate_range_scale(drive, config)
    assert model.scale == pytest.approx(1.07, abs=0.01)
    assert 0.15 < model.sigma0_m < 0.5  # the simulated 0.3 m
    plain = ESTIMATORS["graph-isam2"](config, range_model=LinearCalibration(sigma0_m=0.3)).run(drive)
    calibrated = ESTIMATORS["graph-isam2"](config, range_model=model).run(drive)
    assert rms(position_errors(drive, calibrated)) < 0.85 * rms(position_errors(drive, plain))


def test_wheel_scale_recovered_on_a_simulated_drive():
    """graph-batch self-calibrates the sim's wheel scale error (seed 4: -2.6 %) and gains by it."""
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=4)
    true_scale = 1.0 + drive.params["realised"]["wheel_scale_error"]
    calibrated = ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False), layout="optimized").run(drive)
    plain = ESTIMATORS["graph-batch"](GraphConfig(output_covariance=False, wheel_scale="off"), layout="optimized").run(drive)
    assert calibrated.diagnostics["wheel_scale"] == pytest.approx(true_scale, abs=0.006)
    assert "wheel_scale" not in plain.diagnostics
    assert rms(position_errors(drive, calibrated)) < rms(position_errors(drive, plain))


@pytest.mark.slow
def test_plaza1_accuracy_with_self_calibrated_scale(plaza_path):
    """Plaza1: graph-batch RMS <= 0.40 m, graph-isam2 causal <= 0.55 m.

    The range scale is estimated by the batch smoother from the drive itself
    (truth is used only to score, and for the start pose as for the filters).
    """
    from graphpos.io.plaza import import_plaza

    drive = import_plaza(plaza_path)
    batch = ESTIMATORS["graph-batch"](GraphConfig(range_scale="estimate", output_covariance=False), range_model=LinearCalibration()).run(drive)
    assert batch.diagnostics["range_scale"] == pytest.approx(1.069, abs=0.01)
    assert rms(position_errors(drive, batch)) <= 0.40
    model = calibrate_range_scale(drive)
    causal = ESTIMATORS["graph-isam2"](GraphConfig(output_covariance=False), range_model=model).run(drive)
    assert rms(position_errors(drive, causal)) <= 0.55


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["paper-straight", "paper-comprehensive"])
def test_accuracy_against_the_best_song2016_filter(scenario):
    """Issue 6 targets on the optimized layout: batch <= 0.6 x best filter, iSAM2 <= best filter."""
    from filters import ESTIMATORS as FILTERS
    from graphpos.sim import simulate

    rms_of = {name: [] for name in ("fusion-ekf", "fukf", "graph-isam2", "graph-batch")}
    for seed in range(5):
        drive = simulate(scenario, seed=seed)
        for name in rms_of:
            cls = FILTERS[name] if name in FILTERS else ESTIMATORS[name]
            rms_of[name].append(rms(position_errors(drive, cls(layout="optimized").run(drive))))
    best = min(np.mean(rms_of["fusion-ekf"]), np.mean(rms_of["fukf"]))
    assert np.mean(rms_of["graph-isam2"]) <= best
    assert np.mean(rms_of["graph-batch"]) <= 0.6 * best
