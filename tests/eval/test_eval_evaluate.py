"""The evaluate pipeline: artefacts, failures, process pool against Dask."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from eval.evaluate import evaluate, run_warnings
from eval.execution import Job, execute, executor
from graphpos.errors import MissingChannelError
from graphpos.io import read_drive, read_estimates


def _numbers(results_json: dict) -> list:
    """The accuracy figures of results.json (wall times and RTF differ run to run)."""
    out = []
    for rec in results_json["results"]:
        m = rec["metrics"]
        out.append((rec["estimator"], rec["drive"], m["n_outputs"], m["output_rate_hz"],
                    json.dumps(m["windows"], sort_keys=True)))
    return out


def test_evaluate_writes_every_artefact(tmp_path, drive, test_estimators):
    out = tmp_path / "out"
    outcome = evaluate([(drive, drive)], ["noisy-truth"], out, workers=1, progress=False)
    assert not outcome.failures
    for name in ("results.json", "report.md", "report.html"):
        assert (out / name).stat().st_size > 0
    sub = out / "straight"
    for name in ("trajectories.png", "error_vs_time.png", "error_cdf.png", "speed_error.png", "bound_vs_time.png",
                 "noisy-truth.tum", "noisy-truth.kml", "noisy-truth.geojson", "noisy-truth.csv", "all_estimates.kml",
                 "truth.tum", "truth.csv", "estimates.mcap", "estimates_ros2/metadata.yaml"):
        assert (sub / name).stat().st_size > 0, name
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 5
    md = (out / "report.md").read_text()
    assert "Window: in the tunnel (in_tunnel)" in md and "straight/trajectories.png" in md
    res = json.loads((out / "results.json").read_text())
    whole = res["results"][0]["metrics"]["windows"]["whole"]
    # 0.5 m per axis: RMS of the 2-D error ~ 0.5 sqrt(2), ANEES ~ 2 (consistent)
    assert whole["position"]["rms_m"] == pytest.approx(0.5 * math.sqrt(2), rel=0.15)
    assert whole["nees"]["anees"] == pytest.approx(2.0, rel=0.3)
    assert res["provenance"]["packages"]["numpy"]
    # TUM: 8 columns, one row per output
    tum = np.loadtxt(sub / "noisy-truth.tum")
    assert tum.shape == (len(drive.truth), 8)
    # the MCAP holds the drive and the estimate
    back = read_estimates(sub / "estimates.mcap")
    assert [e.name for e in back] == ["noisy-truth"]
    assert read_drive(sub / "estimates.mcap").truth == drive.truth


def test_failures_are_reported_not_raised(tmp_path, drive, test_estimators):
    outcome = evaluate([(drive, drive)], ["noisy-truth", "broken", "no-such"], tmp_path, workers=1,
                       progress=False, mcap=False)
    errors = {r.job.estimator: r.error for r in outcome.results}
    assert errors["noisy-truth"] is None
    assert "boom" in errors["broken"] and "unknown estimator" in errors["no-such"]
    md = (tmp_path / "report.md").read_text()
    assert "FAILED: RuntimeError: boom" in md and "## Failures" in md
    rec = json.loads((tmp_path / "results.json").read_text())["results"][1]
    assert "RuntimeError" in rec["error"] and "Traceback" in rec["traceback"]


def test_a_run_whose_outputs_cover_part_of_the_drive_is_flagged(tmp_path, drive, test_estimators):
    """A sensor log that ended early ended the track: its RMS was over 9 s of 30 s and nothing said so."""
    t0, t1 = drive.truth.t_s[0], drive.truth.t_s[-1]
    cut = drive.replace(channels={**drive.channels, "gnss": drive.gnss.between(t0, t0 + (t1 - t0) / 3)})
    outcome = evaluate([(cut, cut)], ["noisy-truth"], tmp_path / "cut", workers=1, progress=False, mcap=False)
    whole = outcome.results[0].metrics["windows"]["whole"]
    assert 0.3 < whole["coverage"] < 0.5  # a third, and the outputs stand for the truth a second either side
    said = f"its outputs cover {100 * whole['coverage']:.0f} % of the drive's truth span"
    assert any(said in line for line in run_warnings(outcome.results[0]))
    assert said in (tmp_path / "cut" / "report.md").read_text()
    full = evaluate([(drive, drive)], ["noisy-truth"], tmp_path / "full", workers=1, progress=False, mcap=False)
    assert full.results[0].metrics["windows"]["whole"]["coverage"] == 1.0 and run_warnings(full.results[0]) == []


def test_drive_without_truth_is_refused(tmp_path, drive, test_estimators):
    bare = drive.replace(channels={"wheel": drive.wheel})
    with pytest.raises(MissingChannelError, match="evaluate needs truth"):
        evaluate([(bare, bare)], ["noisy-truth"], tmp_path, progress=False, mcap=False)


def test_a_drive_given_twice_is_refused(tmp_path, drive):
    from eval.evaluate import file_sources
    from graphpos.errors import ConfigError
    from graphpos.io import write_drive

    write_drive(tmp_path / "a.mcap", drive)
    with pytest.raises(ConfigError, match="drive .*a.mcap is given more than once"):
        file_sources([str(tmp_path / "a.mcap"), str(tmp_path / "." / "a.mcap")])  # the same file by two spellings


def test_dask_gives_the_same_numbers_as_the_process_pool(tmp_path, drive, test_estimators):
    distributed = pytest.importorskip("distributed")
    evaluate([(drive, drive)], ["noisy-truth"], tmp_path / "pool", workers=2, progress=False, mcap=False)
    with distributed.LocalCluster(n_workers=1, processes=False, threads_per_worker=1,
                                  dashboard_address=None) as cluster:
        evaluate([(drive, drive)], ["noisy-truth"], tmp_path / "dask", scheduler=cluster.scheduler_address,
                 progress=False, mcap=False)
    pool = json.loads((tmp_path / "pool" / "results.json").read_text())
    dask = json.loads((tmp_path / "dask" / "results.json").read_text())
    assert _numbers(pool) == _numbers(dask)


def test_execute_keeps_job_order(drive, test_estimators):
    jobs = [Job(drive, name) for name in ("broken", "noisy-truth", "broken")]
    results = execute(jobs, workers=2, progress=False)
    assert [r.job.estimator for r in results] == ["broken", "noisy-truth", "broken"]
    assert [r.ok for r in results] == [False, True, False]


def test_the_pool_starts_no_more_processes_than_it_has_tasks():
    """--workers 1000 for one run started 1000 processes (100 s against 5)."""
    with executor(workers=1000, tasks=2) as pool:
        assert pool._max_workers == 2
    with executor(workers=1, tasks=5) as pool:
        assert pool._max_workers == 1


def test_two_drives_of_the_same_name_get_their_own_folders(tmp_path, drive, make_drive, test_estimators):
    other = make_drive(duration_s=5.0)
    evaluate([(drive, drive), (other, other)], ["noisy-truth"], tmp_path, workers=1, progress=False, mcap=False)
    assert (tmp_path / "straight" / "trajectories.png").exists()
    assert (tmp_path / "straight-2" / "trajectories.png").exists()
    res = json.loads((tmp_path / "results.json").read_text())
    assert [r["metrics"]["n_outputs"] for r in res["results"]] == [len(drive.truth), len(other.truth)]


def test_windows_of_identical_bounds_share_one_table(tmp_path, make_drive, test_estimators):
    from graphpos.drive import Window

    base = make_drive()
    drive = base.replace(windows=base.windows + (Window("zone:tunnel", 2.0, 6.0),))
    evaluate([(drive, drive)], ["noisy-truth"], tmp_path, workers=1, progress=False, mcap=False)
    md = (tmp_path / "report.md").read_text()
    assert md.count("Window: ") == 3  # whole, in the tunnel (in_tunnel, zone:tunnel), zone a
    assert "Window: in the tunnel (in_tunnel, zone:tunnel)" in md


def test_evaluate_reports_the_bound_and_efficiency(tmp_path):
    """A short simulated drive: a bound row of each kind and an efficiency column in every window table,
    the bound plot, and the figures in results.json."""
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=0, duration_s=20.0)
    evaluate([(drive, drive)], ["fusion-ekf", "graph-batch"], tmp_path, workers=1, progress=False, mcap=False)
    md = (tmp_path / "report.md").read_text()
    n_tables = md.count("Window: ")
    assert n_tables >= 2 and md.count("| RMS / bound |") == n_tables
    assert md.count("| bound (smoother) |") == md.count("| bound (filtering) |") == n_tables
    assert "(smoother) |" in md and "(filtering) |" in md  # graph-batch against the smoother bound, the EKF the filtering one
    assert (tmp_path / drive.name / "bound_vs_time.png").stat().st_size > 0
    b = json.loads((tmp_path / "results.json").read_text())["drives"][0]["bound"]
    assert b["reason"] is None and b["timing_s"]["total_s"] > 0 and b["keyframes"] > 10
    assert b["bound_kind"] == {"fusion-ekf": "filtering", "graph-batch": "smoother"}
    for window in ("whole", "in_tunnel"):
        smoother, filtering = b["smoother_rms_m"][window], b["filtering_rms_m"][window]
        assert 0 < smoother <= filtering * (1 + 1e-9)
        for name in ("fusion-ekf", "graph-batch"):
            assert b["efficiency"][name][window] > 0
    assert b["is_limit"] and "default noise levels" not in md.split("Bound rows:")[0]


def test_a_bound_with_default_noise_levels_is_called_a_reference():
    """An imported drive carries no noise levels: its bound (graph-batch's defaults) is no lower limit, and
    estimators scored 0.8 of it on a CSV import under a report that said 1 is the best the data allow."""
    from eval.bounds import drive_bound
    from graphpos.sim import simulate

    drive = simulate("paper-straight", seed=0, duration_s=20.0)
    assert drive_bound(drive).is_limit
    imported = drive.replace(params={})
    bound = drive_bound(imported)
    assert bound.ok and not bound.is_limit and bound.bound.diagnostics["noise_levels_known"] is False


def test_rfid_only_rows_say_their_bound_is_of_more_sensors():
    """The bound is of odometry, compass and ranges together: an estimator on ranges alone is marked so."""
    from eval.bounds import bound_label

    assert bound_label("rfid-ekf") == bound_label("multilateration") == "filtering, of more sensors"
    assert bound_label("graph-ranges") == "smoother, of more sensors"  # it smooths its ranges over the whole drive
    assert bound_label("fusion-ekf") == "filtering" and bound_label("graph-batch") == "smoother"


def test_a_bound_that_cannot_be_computed_is_a_dash_and_a_reason(tmp_path, drive, test_estimators, monkeypatch):
    import graphpos.bound
    from graphpos.errors import EstimationError

    def refuse(drive, **_):
        raise EstimationError("graph-batch never starts")

    monkeypatch.setattr(graphpos.bound, "position_bound", refuse)  # forked workers inherit it
    outcome = evaluate([(drive, drive)], ["noisy-truth"], tmp_path, workers=1, progress=False, mcap=False)
    assert not outcome.failures
    md = (tmp_path / "report.md").read_text()
    assert "| bound (smoother) | — (EstimationError: graph-batch never starts) |" in md
    assert "Position bound: — (EstimationError: graph-batch never starts)." in md
    assert not (tmp_path / "straight" / "bound_vs_time.png").exists()
    b = json.loads((tmp_path / "results.json").read_text())["drives"][0]["bound"]
    assert b["reason"] == "EstimationError: graph-batch never starts"
    assert b["smoother_rms_m"]["whole"] is None and b["efficiency"]["noisy-truth"]["whole"] is None
