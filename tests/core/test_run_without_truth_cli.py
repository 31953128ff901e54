"""``graphpos run`` on drives with neither truth nor GNSS.

Every estimator whose channels the drive has runs; one that finds no start
(no pose given, no fixes, ranges that do not determine a start) gives an
empty estimate (``diagnostics["not_started"]``) and ``run`` writes its CSV
with the header only, never a traceback. The drives: a simulated paper
drive without truth and GNSS (every estimator but ``fkf`` starts from the
tags), the same without RFID (dead reckoning only: nothing can start
without a pose), and a drive imported from Plaza-layout data
(:mod:`plaza_samples`) without its truth.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))

from plaza_samples import synthetic_plaza  # noqa: E402

from graphpos.cli import main  # noqa: E402
from graphpos.errors import MissingChannelError  # noqa: E402
from graphpos.estimate import CSV_COLUMNS  # noqa: E402
from graphpos.io import write_drive  # noqa: E402
from graphpos.registry import estimator_classes, make_estimator  # noqa: E402
from graphpos.sim import simulate  # noqa: E402

#: The Plaza-like drive is cut to this many seconds for the run without a start pose: ignition
#: tries a multi-start solve at every range reading there, which costs about 0.1 s each.
PLAZA_CUT_S = 12.0


#: Per-scan RFID estimators (they need no start state).
PER_SCAN = ("multilateration", "rfid-ekf", "lms-federated")
#: Estimators whose fix needs ranges to three tags in one scan (Plaza ranges one beacon at a time: no output).
THREE_RANGES = ("multilateration", "lms-federated")


def _without(drive, *channels):
    return drive.replace(channels={k: v for k, v in drive.channels.items() if k not in channels})


def applicable(drive) -> list[str]:
    """The estimators that accept the drive (its channels suffice)."""
    names = []
    for name in estimator_classes():
        try:
            make_estimator(name).check(drive)
        except MissingChannelError:
            continue
        names.append(name)
    return names


def run(drive, names, folder: Path, *extra: str) -> dict:
    """``graphpos run`` over ``drive`` written to a file; run.json, after checking every CSV."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "drive.mcap"
    write_drive(path, drive)
    out = folder / "out"
    assert main(["run", str(path), *[a for n in names for a in ("-e", n)], *extra, "--out-dir", str(out)]) == 0
    assert not (out / "truth.csv").exists()
    summary = json.loads((out / "run.json").read_text())
    assert set(summary["estimators"]) == set(names)
    for name in names:
        with open(out / f"{name}.csv") as fh:
            rows = list(csv.reader(fh))
        assert tuple(rows[0]) == CSV_COLUMNS, name
        assert len(rows) - 1 == summary["estimators"][name]["outputs"], name
    return summary


@pytest.fixture(scope="module")
def paper_blind():
    return _without(simulate("paper-straight", seed=3, duration_s=20.0).without_truth(), "gnss")


@pytest.fixture(scope="module")
def plaza_blind(tmp_path_factory):
    from graphpos.io.plaza import import_plaza

    mat = tmp_path_factory.mktemp("plaza") / "plaza.mat"
    synthetic_plaza(mat)
    return import_plaza(mat).without_truth()


def test_paper_drive_without_truth_or_gnss_runs_every_estimator_it_can(paper_blind, tmp_path, capsys):
    assert not paper_blind.has("truth") and not paper_blind.has("gnss")
    names = applicable(paper_blind)
    assert set(estimator_classes()) - set(names) == {"fkf"}  # fkf needs position fixes
    summary = run(paper_blind, names, tmp_path)
    for name in names:
        entry = summary["estimators"][name]
        assert entry["outputs"] > 0, f"{name}: {entry['not_started']}"
        if entry["start"] is not None:  # the filters and graphs that need a start found one from the tags
            assert entry["start"]["source"] == "ranges", name


def test_dead_reckoning_drive_cannot_start_and_writes_empty_csvs(paper_blind, tmp_path, capsys):
    """No fixes, no ranges, no pose: nothing can start; every CSV has its header only."""
    drive = _without(paper_blind, "rfid")
    names = applicable(drive)
    assert set(names) == {"dr", "graph-batch", "graph-isam2", "graph-fixed-lag", "graph-fixed-lag-smoothed"}  # graph-ranges needs ranges
    summary = run(drive, names, tmp_path / "none")
    for name in names:
        entry = summary["estimators"][name]
        assert entry["outputs"] == 0 and entry["start"] is None, name
        assert entry["not_started"] and entry["diagnostics"]["not_started"] == entry["not_started"], name
    assert "not started" in capsys.readouterr().out
    # the same drive with a start pose: every one of them runs from it
    summary = run(drive, names, tmp_path / "posed", "--initial-pose", "0,-1.5,0")
    for name in names:
        entry = summary["estimators"][name]
        assert entry["outputs"] > 0 and entry["start"]["source"] == "user" and entry["not_started"] is None, name


def test_plaza_like_drive_with_a_start_pose(plaza_blind, tmp_path, capsys):
    """Every estimator Plaza's sensors allow (UWB ranges, odometry, gyro: no compass, no accelerometers)."""
    names = applicable(plaza_blind)
    assert {"dr", "rfid-ekf", "fusion-ekf", "graph-isam2", "graph-batch"} <= set(names)
    assert not {"ekf-ca", "fkf"} & set(names)
    # the synthetic robot starts at (20, 0) m heading north
    summary = run(plaza_blind, names, tmp_path, "--initial-pose", "20,0,90")
    for name in names:
        entry = summary["estimators"][name]
        if entry["start"] is not None:
            assert entry["start"]["source"] == "user", name
        else:  # per-scan RFID estimators, which need no start state
            assert name in PER_SCAN, name
        if name not in THREE_RANGES:
            assert entry["outputs"] > 0 and entry["not_started"] is None, name


def test_plaza_like_drive_without_a_start_pose_does_not_crash(plaza_blind, tmp_path, capsys):
    """Ranges to one beacon at a time, no compass, no pose: each estimator starts when ignition
    can, or gives an empty estimate saying why."""
    cut = plaza_blind.replace(channels={k: ch.between(plaza_blind.start_s, plaza_blind.start_s + PLAZA_CUT_S)
                                        for k, ch in plaza_blind.channels.items()})
    names = ["dr", "multilateration", "rfid-ekf", "graph-isam2"]
    summary = run(cut, names, tmp_path)
    for name in ("dr", "graph-isam2"):
        entry = summary["estimators"][name]
        assert (entry["outputs"] > 0 and entry["start"]["source"] == "ranges") or (entry["outputs"] == 0 and entry["not_started"]), name


def test_evaluate_reports_estimators_that_did_not_start(tmp_path, capsys):
    """``evaluate`` on a drive with truth but nothing to start from: no crash, an empty run said so."""
    drive = _without(simulate("paper-straight", seed=3, duration_s=10.0), "gnss", "rfid")
    path = tmp_path / "dr-only.mcap"
    write_drive(path, drive)
    out = tmp_path / "out"
    assert main(["evaluate", str(path), "-e", "dr,graph-isam2", "-o", str(out), "--workers", "1", "--no-progress"]) == 0
    results = json.loads((out / "results.json").read_text())
    for r in results["results"]:
        assert r["error"] is None and r["start"] is None, r["estimator"]
        assert r["metrics"]["n_outputs"] == 0 and r["metrics"]["diagnostics"]["not_started"], r["estimator"]
    assert (out / "report.md").read_text().count("| not started: ") >= 2
