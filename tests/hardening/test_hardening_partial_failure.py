"""One estimator's failure never costs the others their results (issue 14, items 3 and 7).

``run`` writes the outputs of the estimators that finished, prints one line
on stderr per estimator that failed (naming it and the reason), records each
estimator's status in run.json and exits with status 1; when every estimator
fails it writes nothing. ``evaluate`` reports each failure in the report,
results.json and on stderr, names what failed (never the output folder) and
exits with status 1.

Failures are made in-process: an estimator class's ``run`` is replaced by
one that raises (the process-pool workers of ``evaluate`` are forked, so
they inherit it).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from graphpos.cli import main
from graphpos.errors import EstimationError
from graphpos.io import read_estimates, write_drive
from graphpos.registry import estimator_classes
from graphpos.sim import simulate
from output_files import export_files  # tests/io, on the import path (conftest.py)


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    write_drive(path, simulate("paper-straight", seed=1, duration_s=12.0))
    return path


def fail(monkeypatch, name: str, exc: Exception) -> None:
    """Make estimator ``name`` raise ``exc`` from its run."""

    def run(self, drive):
        raise exc

    monkeypatch.setattr(estimator_classes()[name], "run", run)


def cli(capsys, *argv) -> tuple[int, list[str], str]:
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, err.strip().splitlines(), out


def _tree(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


# -- run ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("exc, internal", [
    (EstimationError("GTSAM failed: under-constrained or ill-conditioned system"), False),
    (RuntimeError("boom"), True),
    (MemoryError("out of memory"), True),
], ids=["estimation-error", "bug", "memory"])
def test_run_writes_what_finished(monkeypatch, capsys, tmp_path, drive_file, exc, internal):
    fail(monkeypatch, "rfid-ekf", exc)
    out = tmp_path / "out"
    status, err, stdout = cli(capsys, "run", drive_file, "-e", "dr", "-e", "rfid-ekf", "-e", "fusion-ekf",
                              "--out-dir", out)
    assert status == 1
    assert len(err) == 1 and err[0].startswith("graphpos run: error: rfid-ekf failed: "), err
    assert str(exc) in err[0] and ("internal error" in err[0]) == internal and "Traceback" not in err[0]
    assert {p.name for p in out.iterdir()} == {*export_files(["dr", "fusion-ekf"]), "run.json"}
    summary = json.loads((out / "run.json").read_text())
    assert summary["failed"] == ["rfid-ekf"]
    records = summary["estimators"]
    assert records["dr"]["status"] == records["fusion-ekf"]["status"] == "ok"
    assert records["rfid-ekf"]["status"] == "failed" and str(exc) in records["rfid-ekf"]["error"]
    assert (records["rfid-ekf"]["traceback"] is not None) == internal
    assert records["fusion-ekf"]["outputs"] > 0
    assert {e.name for e in read_estimates(out / "estimates.mcap")} == {"dr", "fusion-ekf"}
    assert "dr.csv" in stdout and "rfid-ekf" not in stdout


def test_run_reports_every_failure_in_its_own_line(monkeypatch, capsys, tmp_path, drive_file):
    fail(monkeypatch, "rfid-ekf", EstimationError("no fix"))
    fail(monkeypatch, "fusion-ekf", ValueError("bad\nvalue"))
    out = tmp_path / "out"
    status, err, _ = cli(capsys, "run", drive_file, "-e", "rfid-ekf", "-e", "dr", "-e", "fusion-ekf", "--out-dir", out)
    assert status == 1
    assert [line.split(" failed: ")[0] for line in err] == ["graphpos run: error: rfid-ekf",
                                                            "graphpos run: error: fusion-ekf"]
    assert "bad\\nvalue" in err[1]  # a newline in a message stays one line
    assert json.loads((out / "run.json").read_text())["failed"] == ["rfid-ekf", "fusion-ekf"]
    assert (out / "dr.csv").is_file()


@pytest.mark.parametrize("exc, status", [(EstimationError("no fix"), 2), (RuntimeError("boom"), 1)],
                         ids=["user-errors", "bug"])
def test_run_where_every_estimator_fails_writes_nothing(monkeypatch, capsys, tmp_path, drive_file, exc, status):
    for name in ("dr", "rfid-ekf"):
        fail(monkeypatch, name, exc)
    before = _tree(tmp_path)
    code, err, _ = cli(capsys, "run", drive_file, "-e", "dr", "-e", "rfid-ekf", "--out-dir", tmp_path / "out")
    assert code == status
    assert len(err) == 2 and all(" failed: " in line and str(exc) in line for line in err), err
    assert all("folder" not in line for line in err), "blames the output folder"
    assert _tree(tmp_path) == before


def test_run_failure_keeps_the_previous_output(monkeypatch, capsys, tmp_path, drive_file):
    """A rerun in which every estimator fails leaves the earlier, complete output in place."""
    out = tmp_path / "out"
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 0
    before = (out / "dr.csv").read_bytes()
    fail(monkeypatch, "dr", EstimationError("no fix"))
    assert cli(capsys, "run", drive_file, "-e", "dr", "--out-dir", out)[0] == 2
    assert (out / "dr.csv").read_bytes() == before and (out / "run.json").is_file()


# -- evaluate ----------------------------------------------------------------------------------------------------
def evaluate(capsys, drives, names, out):
    return cli(capsys, "evaluate", *drives, *(a for n in names for a in ("-e", n)), "-o", out, "--workers", "1",
               "--no-progress")


def test_evaluate_writes_what_finished(monkeypatch, capsys, tmp_path, drive_file):
    fail(monkeypatch, "rfid-ekf", EstimationError("GTSAM failed: under-constrained"))
    out = tmp_path / "eval"
    status, err, _ = evaluate(capsys, [drive_file], ["dr", "rfid-ekf"], out)
    assert status == 1
    assert any(line.strip().startswith("rfid-ekf on ") and "GTSAM failed" in line for line in err), err
    results = json.loads((out / "results.json").read_text())
    by = {r["estimator"]: r for r in results["results"]}
    assert by["dr"]["error"] is None and by["dr"]["metrics"]["n_outputs"] > 0
    assert "GTSAM failed" in by["rfid-ekf"]["error"]
    sub = out / results["drives"][0]["name"]
    assert (sub / "dr.csv").is_file() and not (sub / "rfid-ekf.csv").exists()
    assert "FAILED" in (out / "report.md").read_text()


@pytest.mark.parametrize("exc", [EstimationError("no fix"), RuntimeError("boom")], ids=["estimation-error", "bug"])
def test_evaluate_says_what_failed_when_every_estimator_fails(monkeypatch, capsys, tmp_path, drive_file, exc):
    for name in ("dr", "rfid-ekf"):
        fail(monkeypatch, name, exc)
    out = tmp_path / "eval"
    status, err, _ = evaluate(capsys, [drive_file], ["dr", "rfid-ekf"], out)
    assert status == 1
    assert "Traceback" not in "\n".join(err)
    assert sum(str(exc) in line for line in err) == 2 and not any("cannot write" in line for line in err), err
    report = (out / "report.md").read_text()
    assert "## Failures" in report
    assert all(f"| {name} | {type(exc).__name__}: {exc} |" in report for name in ("dr", "rfid-ekf"))
    assert "No estimator gave a track on this drive" in report
    assert not [p for p in out.rglob("*") if p.is_dir() and not any(p.iterdir())], "an empty folder is left"


def test_evaluate_one_drive_failing_keeps_the_other(monkeypatch, capsys, tmp_path, drive_file):
    """Every estimator failing on one drive does not cost the other drive its results."""
    other = tmp_path / "other.mcap"
    write_drive(other, simulate("paper-straight", seed=2, duration_s=8.0).replace(name="other"))
    real_run = estimator_classes()["dr"].run

    def run(self, drive):
        if drive.name == "other":
            raise EstimationError("no fix on this drive")
        return real_run(self, drive)

    monkeypatch.setattr(estimator_classes()["dr"], "run", run)
    out = tmp_path / "eval"
    status, err, _ = evaluate(capsys, [drive_file, other], ["dr"], out)
    assert status == 1 and any("dr on other" in line and "no fix" in line for line in err), err
    results = json.loads((out / "results.json").read_text())
    assert [r["error"] is None for r in results["results"]] == [True, False]
    first = results["drives"][0]["name"]
    assert (out / first / "dr.csv").is_file() and (out / "other" / "estimates.mcap").is_file()
