"""reproduce and layout-study on short simulated drives (the full quick run is slow-marked)."""

from __future__ import annotations

import json

import pytest

from eval import reproduce as reproduce_module
from eval.experiments import Experiment, Row, experiments
from eval.layout_study import layout_study
from graphpos.cli import main


def test_every_published_table_is_listed():
    keys = {e.key for e in experiments()}
    assert {"song2016-table2", "song2016-table3", "song2016b-tableI", "song2014-table2", "song2014-table4-whole",
            "song2014-table4-tunnel", "song2014-table5", "song2014-table6", "liu2016-zones"} <= keys
    assert sum(k.startswith("song2016-table4/") for k in keys) == 7
    from graphpos.sim import SCENARIOS

    for e in experiments():  # every drive they ask for exists in the simulator
        assert e.scenario in SCENARIOS
        assert e.pattern is None or e.pattern in SCENARIOS[e.scenario].patterns


def test_reproduce_tables_with_failures_in_cells(tmp_path, monkeypatch):
    tiny = [Experiment(key="t", paper="p", title="tiny table", scenario="paper-straight", window="in_tunnel",
                       rows=(Row("rfid-ekf", "RFID-EKF", (9.27, 5.07)), Row("no-such", "Missing", (1.0, 1.0))),
                       extra=())]
    monkeypatch.setattr(reproduce_module, "experiments", lambda: tiny)
    monkeypatch.setattr(reproduce_module, "DEGRADED_ESTIMATORS", (("rfid-ekf", "dense"),))
    monkeypatch.setattr(reproduce_module, "default_plaza_path", lambda: tmp_path / "absent.mat")
    outcome = reproduce_module.reproduce(tmp_path / "out", seeds=2, workers=1, progress=False)
    md = (tmp_path / "out" / "report.md").read_text()
    assert "| RFID-EKF | dense | 9.27 | 5.07 |" in md
    assert "FAILED: ConfigError: unknown estimator 'no-such'" in md
    assert "Late measurements and faults" in md and "fault:rfid_blackout" in md and "Plaza" in md and "song2016 Table 1" in md
    assert [r.job.estimator for r in outcome.failures] == ["no-such", "no-such"]
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    row = res["tables"]["t"]["rows"][0]
    assert len(row["rms_m"]) == 2 and all(v > 0 for v in row["rms_m"])
    assert (tmp_path / "out" / "report.html").read_text().count("data:image/png") >= 2


def test_layout_study_curve(tmp_path):
    outcome = layout_study("paper-straight", tmp_path, seeds=1, estimators=["rfid-ekf"], workers=1,
                           progress=False, duration_s=40.0)
    assert not outcome.failures
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["n_tags"]["dense"] > res["n_tags"]["optimized"] > 0
    assert {c["layout"] for c in res["curve"]} >= {"dense", "optimized"}
    assert (tmp_path / "cost_accuracy.png").stat().st_size > 0


@pytest.mark.slow
def test_reproduce_quick_end_to_end(tmp_path):
    code = main(["reproduce", "--quick", "-o", str(tmp_path), "--no-progress"])
    for name in ("report.md", "report.html", "results.json"):
        assert (tmp_path / name).stat().st_size > 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert {"song2016-table1", "song2016-table2", "song2016-table3", "song2016b-tableI", "song2014-table5",
            "liu2016-zones", "degraded"} <= set(res["tables"])
    failed = [r for r in res["runs"] if r["error"] and not r["not_applicable"]]
    assert code == (1 if failed else 0)
