"""The graph estimators from the command line: ``--final``, ``--set``, and `graphpos evaluate` settings."""

from __future__ import annotations

import json

import numpy as np
import pytest
from graph_drives import synthetic_drive

from graphpos.cli import main
from graphpos.io import read_estimates, write_drive
from graphpos.registry import make_estimator


@pytest.fixture(scope="module")
def drive():
    return synthetic_drive(20, seed=3, turn_radps=0.05)


@pytest.fixture(scope="module")
def drive_file(drive, tmp_path_factory):
    path = tmp_path_factory.mktemp("drive") / "d.mcap"
    write_drive(path, drive)
    return path


def test_final_flag_gives_the_smoothed_trajectory(drive, drive_file, tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(drive_file), "-e", "graph-isam2", "-e", "graph-fixed-lag", "--final", "--set", "fixed_lag_s=12",
                 "--out-dir", str(out)]) == 0
    written = {e.name: e for e in read_estimates(out / "estimates.mcap")}
    final = make_estimator("graph-isam2", settings={"final": "true", "fixed_lag_s": "12"}).run(drive)
    causal = make_estimator("graph-isam2").run(drive)
    np.testing.assert_allclose(written["graph-isam2"].position, final.position, atol=1e-9)
    # the causal output starts at the start-up keyframe, the smoothed one at the drive's start
    since_start = np.isin(np.round(final.t_s, 6), np.round(causal.t_s, 6))
    assert since_start.sum() == len(causal) and len(final) >= len(causal)
    assert np.abs(final.position[since_start] - causal.position).max() > 0.01  # smoothing changed the past
    summary = json.loads((out / "run.json").read_text())["estimators"]
    assert summary["graph-isam2"]["settings"] == {"fixed_lag_s": "12", "final": "true"}
    assert summary["graph-isam2"]["config"]["final"] is True
    assert summary["graph-fixed-lag"]["settings"] == {"fixed_lag_s": "12"}
    assert summary["graph-fixed-lag"]["config"]["final"] is False and summary["graph-fixed-lag"]["config"]["fixed_lag_s"] == 12.0


@pytest.mark.parametrize(
    "args, message",
    [
        (["-e", "graph-batch", "--final"], "--final applies to graph-isam2"),
        (["-e", "graph-isam2", "--set", "fixed_lag_s=soon"], "expected a number"),
        (["-e", "graph-isam2", "--set", "graph-batch.final=true"], "not selected"),
        (["-e", "fusion-ekf", "--set", "fixed_lag_s=20"], "no selected estimator"),
    ],
)
def test_bad_settings_are_one_line_errors(drive_file, tmp_path, capsys, args, message):
    out = tmp_path / "out"
    assert main(["run", str(drive_file), *args, "--out-dir", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert not out.exists()


def test_evaluate_applies_and_records_settings(drive, drive_file, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["evaluate", str(drive_file), "-e", "graph-isam2", "--final", "--workers", "1", "--no-progress", "-o", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["settings"] == {"graph-isam2": {"final": "true"}}
    assert results["results"][0]["config"]["final"] is True
    final = make_estimator("graph-isam2", settings={"final": "true"}).run(drive)
    truth_east = np.interp(final.t_s, drive.truth.t_s, drive.truth.east_m)
    truth_north = np.interp(final.t_s, drive.truth.t_s, drive.truth.north_m)
    rms_m = np.sqrt(np.mean((final.east_m - truth_east) ** 2 + (final.north_m - truth_north) ** 2))
    assert results["results"][0]["metrics"]["windows"]["whole"]["position"]["rms_m"] == pytest.approx(rms_m, rel=1e-6)
    assert "graph-isam2 settings: final=true" in (out / "report.md").read_text()
