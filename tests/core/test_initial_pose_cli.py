"""``--initial-pose`` on ``graphpos run`` and ``graphpos evaluate``.

The pose reaches every selected estimator (``initial_pose=``), which starts
there at the first measurement (``diagnostics["start"]["source"] == "user"``)
on a drive that has neither truth nor GNSS; the pose is recorded in run.json
/ results.json; a bad value is one line on stderr, exit status 2, nothing
written.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))

from output_files import export_files  # noqa: E402

from graphpos.cli import main  # noqa: E402
from graphpos.estimate import CSV_COLUMNS  # noqa: E402
from graphpos.io import write_drive  # noqa: E402
from graphpos.sim import simulate  # noqa: E402

#: Near the simulated start (0, -1.5) m heading east, but not on it: the
#: output must start at the given pose, not at a found one.
POSE = (1.0, -2.0, 3.0, 0.5, 2.0)  # E, N, yaw deg, sigma m, sigma yaw deg
POSE_TEXT = ",".join(f"{v:g}" for v in POSE)
ESTIMATORS = ("fusion-ekf", "graph-isam2")


@pytest.fixture(scope="module")
def sim():
    return simulate("paper-straight", seed=2, duration_s=20.0)


def _without(drive, *channels):
    return drive.replace(channels={k: v for k, v in drive.channels.items() if k not in channels})


@pytest.fixture(scope="module")
def blind_file(sim, tmp_path_factory):
    """The drive with neither truth (nor true ranges) nor GNSS."""
    path = tmp_path_factory.mktemp("blind") / "blind.mcap"
    write_drive(path, _without(sim.without_truth(), "gnss"))
    return path


@pytest.fixture(scope="module")
def no_gnss_file(sim, tmp_path_factory):
    """The drive with truth (for evaluate) but no GNSS."""
    path = tmp_path_factory.mktemp("nognss") / "nognss.mcap"
    write_drive(path, _without(sim, "gnss"))
    return path


def _first_row(path):
    with open(path) as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == CSV_COLUMNS
    return [float(x) if x else math.nan for x in rows[1]]


def _assert_pose_record(record):
    e, n, yaw_deg, sigma_m, sigma_yaw_deg = POSE
    assert record["east_m"] == e and record["north_m"] == n
    assert record["yaw_rad"] == pytest.approx(math.radians(yaw_deg)) and record["yaw_deg"] == pytest.approx(yaw_deg)
    assert record["position_sigma_m"] == sigma_m and record["yaw_sigma_deg"] == pytest.approx(sigma_yaw_deg)


def test_run_starts_every_estimator_at_the_given_pose(blind_file, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["run", str(blind_file), *[a for n in ESTIMATORS for a in ("-e", n)], "--initial-pose", POSE_TEXT, "--out-dir", str(out)]
    assert main(args) == 0
    assert {p.name for p in out.iterdir()} == {*export_files(ESTIMATORS, truth=False), "run.json"}  # no truth.*
    summary = json.loads((out / "run.json").read_text())
    _assert_pose_record(summary["initial_pose"])
    for name in ESTIMATORS:
        entry = summary["estimators"][name]
        start = entry["start"]
        assert start == entry["diagnostics"]["start"]
        assert start["source"] == "user", name
        assert (start["east_m"], start["north_m"]) == (POSE[0], POSE[1])
        assert start["position_sigma_m"] == POSE[3] and start["yaw_sigma_rad"] == pytest.approx(math.radians(POSE[4]))
        assert entry["not_started"] is None and entry["outputs"] > 100
        t, east, north = _first_row(out / f"{name}.csv")[:3]
        assert t == pytest.approx(0.0, abs=0.11), name  # at the first measurement, not after a search
        assert math.hypot(east - POSE[0], north - POSE[1]) < 0.3, name


def test_without_a_pose_they_start_later_from_the_ranges(blind_file, tmp_path, capsys):
    """The control: the same drive without --initial-pose starts from the tags, seconds in."""
    out = tmp_path / "out"
    assert main(["run", str(blind_file), *[a for n in ESTIMATORS for a in ("-e", n)], "--out-dir", str(out)]) == 0
    summary = json.loads((out / "run.json").read_text())
    assert summary["initial_pose"] is None
    for name in ESTIMATORS:
        start = summary["estimators"][name]["start"]
        assert start is not None and start["source"] != "user", name
        assert _first_row(out / f"{name}.csv")[0] > 1.0, name


def test_evaluate_passes_and_records_the_pose(no_gnss_file, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["evaluate", str(no_gnss_file), "-e", ",".join(ESTIMATORS), "--initial-pose", POSE_TEXT, "-o", str(out),
            "--workers", "1", "--no-progress"]
    assert main(args) == 0
    results = json.loads((out / "results.json").read_text())
    _assert_pose_record(results["initial_pose"])
    assert {r["estimator"] for r in results["results"]} == set(ESTIMATORS)
    for r in results["results"]:
        assert r["error"] is None, r["error"]
        _assert_pose_record(r["initial_pose"])
        assert r["start"]["source"] == "user" and r["start"] == r["metrics"]["diagnostics"]["start"]
        assert (r["start"]["east_m"], r["start"]["north_m"]) == (POSE[0], POSE[1])
    assert "Start pose given" in (out / "report.md").read_text()


@pytest.mark.parametrize("value", ["1,2", "1,2,x", "1,2,3,0", "1,2,3,1,-5", "nan,2,3", "1,2,3,4,5,6", "2e9,0,0"])
@pytest.mark.parametrize("command", ["run", "evaluate"])
def test_a_bad_pose_is_one_line_exit_2_nothing_written(command, value, no_gnss_file, tmp_path, capsys):
    out = tmp_path / "out"
    where = ["--out-dir", str(out)] if command == "run" else ["-o", str(out), "--workers", "1", "--no-progress"]
    code = main([command, str(no_gnss_file), "-e", "fusion-ekf", "--initial-pose", value, *where])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith(f"graphpos {command}: error:") and "initial pose" in err
    assert "Traceback" not in err
    assert not out.exists()
