"""Every estimator through every injected fault: no exception, the output
rate kept, covariances positive definite, the error during an RFID blackout
growing smoothly and recovering after it.

The fast suite runs every estimator through an RFID blackout and a
representative set of estimators through every fault on short drives; the
full matrix (every estimator x every fault, the GNSS faults on a drive with
GNSS) is marked slow. The figures are those of ``graphpos fault-study``
(:mod:`eval.faults`), so the study and the tests measure the same thing.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from eval.faults import (RECOVERY_HOLD_S, WHOLE_DRIVE, fault_figures, fault_source, fault_span, recovery_time,
                         run_one, study_faults)
from eval.execution import load_drive
from graphpos.registry import estimator_classes
from graphpos.sim.faults import FAULTS

ESTIMATORS = list(estimator_classes())
#: Drives: a short RFID tunnel drive (2 m/s, ~36 s of tunnel), an urban drive reaching its RSU tunnel (for
#: fkf) and the urban drive's first minute, on open road with GNSS (for the GNSS faults).
FAST_DRIVE = ("paper-straight", 45.0)
FIXES_DRIVE = ("urban-rsu-gnss", 120.0)
GNSS_DRIVE = ("urban-rsu-gnss", 60.0)
FULL_DRIVES = (("paper-comprehensive", None), ("long-tunnel", None), ("urban-rsu-gnss", None))
#: Estimators taken through every fault in the fast suite (one of each family).
FAST_SUBSET = ("dr", "rfid-ekf", "fusion-ekf", "imm-stekf", "fkf", "graph-isam2")
#: Largest change of the error between two outputs while no tag is heard (2 m/s, 10 Hz: a smooth drift).
SMOOTH_STEP_M = 0.5
#: An estimator that uses ranges is back within its band this soon after the blackout ends.
RECOVERY_MAX_S = 15.0


def _cases(estimators, faults):
    return [(e, f) for e in estimators for f in faults]


@functools.lru_cache(maxsize=None)
def _specs(scenario: str, duration_s: float | None) -> dict:
    return study_faults(load_drive(fault_source(scenario, 0, duration_s, None, None)))


@functools.lru_cache(maxsize=None)
def _run(scenario: str, duration_s: float | None, fault: str | None, estimator: str) -> dict:
    spec = _specs(scenario, duration_s).get(fault) if fault else None
    return run_one(fault_source(scenario, 0, duration_s, fault, spec), estimator)


def _figures(scenario: str, duration_s: float | None, fault: str, estimator: str) -> dict | None:
    """The study's figures of one run, after checking it raised nothing; None if not applicable."""
    spec = _specs(scenario, duration_s)[fault]
    if not isinstance(spec, dict):
        return None
    base = _run(scenario, duration_s, None, estimator)
    if base["not_applicable"]:
        return None
    assert base["error"] is None, base.get("traceback") or base["error"]
    run = _run(scenario, duration_s, fault, estimator)
    assert run["error"] is None, run.get("traceback") or run["error"]
    span = fault_span(load_drive(fault_source(scenario, 0, duration_s, fault, spec)), fault)
    return fault_figures(run, base, span)


#: Multilateration and LMS-federated fix one scan from its own readings (at
#: least three tags at once): when the readings of a scan arrive split over
#: several instants, the pieces are applied at arrival and some hold too few
#: tags for a fix, so fewer outputs is their correct behaviour.
SCAN_SPLIT_BY_LATENESS = {("multilateration", "late_readings"), ("lms-federated", "late_readings")}


def _check_health(figs: dict, fault: str, estimator: str) -> None:
    assert figs["rate_kept"] or (estimator, fault) in SCAN_SPLIT_BY_LATENESS, f"{estimator} lost its output rate with {fault}: {figs['n_outputs']} outputs, " \
                              f"{figs['n_outputs_fault_free']} fault-free"
    assert figs["cov_pd"] in (True, None), f"{estimator} with {fault}: covariance not positive definite " \
                                          f"(smallest eigenvalue {figs['cov_min_eig_m2']})"


def _check_blackout(figs: dict, estimator: str) -> None:
    uses_ranges = estimator != "dr"
    if figs["n_outputs"] and np.isfinite(figs["max_step_during_m"]):
        assert figs["max_step_during_m"] <= SMOOTH_STEP_M, f"{estimator}: error jumps during the blackout"
    if uses_ranges:
        assert figs["recovered"], f"{estimator} did not recover after the blackout " \
                                  f"(threshold {figs['recovery_threshold_m']:.2f} m)"
        assert figs["recovery_s"] <= RECOVERY_MAX_S


def test_recovery_time_definition():
    t = np.arange(0.0, 30.0, 0.1)
    spike = np.where((t > 10.0) & (t < 14.0), 5.0, 0.2)
    assert recovery_time(t, spike, 10.0, 1.0) == pytest.approx(4.0, abs=0.11)
    assert recovery_time(t, np.full(t.size, 0.2), 10.0, 1.0) == 0.0
    assert recovery_time(t, np.full(t.size, 5.0), 10.0, 1.0) is None
    # Dipping under the threshold for less than the hold time is not recovery.
    flicker = np.where((t > 12.0) & (t < 12.0 + RECOVERY_HOLD_S - 1.0), 0.2, 5.0)
    flicker[t > 20.0] = 0.2
    assert recovery_time(t, flicker, 10.0, 1.0) == pytest.approx(10.0, abs=0.11)
    # Clear up to the end of the drive, sooner than the hold time, counts.
    late = np.where(t < 27.0, 5.0, 0.2)
    assert recovery_time(t, late, 10.0, 1.0) == pytest.approx(17.0, abs=0.11)


def test_study_places_every_fault():
    specs = _specs(*FAST_DRIVE)
    assert set(specs) == set(FAULTS)
    assert all(isinstance(specs[k], dict) for k in FAULTS)
    paper = load_drive(fault_source(FAST_DRIVE[0], 0, FAST_DRIVE[1], None, None))
    jump = specs["gnss_jump"]  # a paper drive's GNSS is its DGPS approach: the fault falls there
    assert paper.gnss.t_s[0] <= jump["start_s"] and jump["start_s"] + jump["duration_s"] <= paper.gnss.t_s[-1] + 1.0
    urban = _specs(*FIXES_DRIVE)
    drive = load_drive(fault_source(FIXES_DRIVE[0], 0, FIXES_DRIVE[1], None, None))
    jump = urban["gnss_jump"]
    fixes = drive.gnss.t_s[(drive.gnss.t_s >= jump["start_s"]) & (drive.gnss.t_s <= jump["start_s"] + jump["duration_s"])]
    assert fixes.size >= 0.8 * jump["duration_s"]  # the GNSS fault falls where there are fixes


@pytest.mark.parametrize("estimator", [e for e in ESTIMATORS if e != "fkf"])
def test_every_estimator_through_an_rfid_blackout(estimator):
    figs = _figures(*FAST_DRIVE, "rfid_blackout", estimator)
    _check_health(figs, "rfid_blackout", estimator)
    _check_blackout(figs, estimator)


def test_fkf_through_an_rsu_blackout():
    figs = _figures(*FIXES_DRIVE, "rfid_blackout", "fkf")
    _check_health(figs, "rfid_blackout", "fkf")
    assert figs["recovered"]


@pytest.mark.parametrize("estimator, fault", _cases(FAST_SUBSET, [f for f in FAULTS if f != "rfid_blackout"]))
def test_estimators_through_each_fault(estimator, fault):
    drive = GNSS_DRIVE if fault.startswith("gnss_") else FIXES_DRIVE if estimator == "fkf" else FAST_DRIVE
    figs = _figures(*drive, fault, estimator)
    if figs is None:
        pytest.skip(f"{estimator} or {fault} does not apply to {drive[0]}")
    _check_health(figs, fault, estimator)
    if fault not in WHOLE_DRIVE and estimator in ("fusion-ekf", "imm-stekf", "graph-isam2") and fault != "compass_disturbance":
        assert figs["recovered"], f"{estimator} did not recover from {fault}"


@pytest.mark.slow
@pytest.mark.parametrize("estimator, fault", _cases(ESTIMATORS, FAULTS))
@pytest.mark.parametrize("scenario, duration_s", FULL_DRIVES)
def test_full_matrix(scenario, duration_s, estimator, fault):
    figs = _figures(scenario, duration_s, fault, estimator)
    if figs is None:
        pytest.skip(f"{estimator} or {fault} does not apply to {scenario}")
    _check_health(figs, fault, estimator)
    if fault == "rfid_blackout" and scenario.startswith("paper-"):
        _check_blackout(figs, estimator)


def test_fault_study_command_writes_its_report(tmp_path, capsys):
    from graphpos.cli import main

    out = tmp_path / "study"
    status = main(["fault-study", "paper-straight", "--duration", "30", "-e", "dr,rfid-ekf", "-e", "fusion-ekf",
                   "--seeds", "1", "--workers", "1", "--no-progress", "-o", str(out)])
    assert status == 0, capsys.readouterr().err
    results = json.loads((out / "results.json").read_text())
    assert results["estimators"] == ["dr", "rfid-ekf", "fusion-ekf"]
    cells = {(c["fault"], c["estimator"]): c["seeds"][0] for c in results["cells"]}
    applicable = [k for k, v in results["faults"].items() if isinstance(v, dict)]
    assert set(cells) == {(f, e) for f in ["none", *applicable] for e in results["estimators"]}
    blackout = cells[("rfid_blackout", "fusion-ekf")]
    assert blackout["during_rms_m"] > 0 and blackout["recovery_threshold_m"] > blackout["baseline_rms_m"]
    report = (out / "report.md").read_text()
    assert "| rfid_blackout |" in report and (out / "fault_errors.png").stat().st_size > 0


@pytest.mark.parametrize("argv, message", [
    (["nope"], "unknown scenario"),
    (["paper-straight", "-e", "nope"], "unknown estimator"),
    (["paper-straight", "--seeds", "0"], "--seeds"),
    (["paper-straight", "--duration", "-3"], "--duration"),
    (["paper-straight", "-o", "{file}"], "not a folder"),
    (["paper-straight", "-o", "{missing}/deeper"], "does not exist"),
])
def test_fault_study_bad_options(tmp_path, capsys, argv, message):
    from graphpos.cli import main

    (tmp_path / "file").write_text("x")
    argv = [a.format(file=tmp_path / "file", missing=tmp_path / "missing") for a in argv]
    if "-o" not in argv:
        argv += ["-o", str(tmp_path / "out")]
    before = sorted(tmp_path.rglob("*"))
    assert main(["fault-study", *argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert sorted(tmp_path.rglob("*")) == before
