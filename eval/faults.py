"""``graphpos fault-study``: every estimator through every fault, measured.

Each seed gives one fault-free drive of the scenario and, for every fault
kind of :mod:`graphpos.sim.faults`, the same drive with that one fault
injected (the simulator draws faults from their own random streams, so the
faulted drive equals the fault-free one outside the fault). Every estimator
runs on all of them, without their truth (truth is for scoring only, issue
13: :meth:`graphpos.drive.Drive.without_truth`); the worker returns the
error series (the Euclidean position error against the truth interpolated
at the output epochs, as in :mod:`eval.metrics`) and the health checks
below, and the figures are computed here.

Where the faults are placed
---------------------------
The study places each episode where it means something (the simulator's
default, 30 % into the drive, may fall where the faulted sensor is silent):

- RFID/RSU and odometry episodes (``rfid_blackout``, ``nlos_burst``,
  ``wheel_slip``, ``compass_disturbance``) start a quarter into the first
  ``in_tunnel`` window (the whole drive if there is none) and last the
  kind's default, at most 40 % of that window, so part of the tunnel is left
  to recover in;
- GNSS episodes (``gnss_jump``, ``gnss_multipath``) go the same way into the
  longest stretch with GNSS fixes (fixes at most 2 s apart);
- ``dead_tags``, ``clock_offset`` (on ``rfid``, else ``rsu``, else ``gnss``),
  ``dropped_samples``, ``duplicated_samples`` and ``late_readings`` act on
  the whole drive: they have an error "during" but no "after" and no
  recovery time.

A fault whose sensor the scenario lacks (GNSS faults on a paper drive) is
reported as not applicable; so is an estimator that refuses the scenario
for lacking a channel (``fkf`` without RSU or GNSS).

Figures per (fault, estimator, seed)
------------------------------------
``during``: max and RMS error over the outputs inside the fault window;
``after``: the same from the fault's end to the end of the drive;
``baseline_rms_m``: the estimator's RMS over the whole fault-free drive.

Recovery time: with the threshold
``RECOVERY_FACTOR * baseline_rms_m + RECOVERY_MARGIN_M`` (1.5 x the
estimator's own fault-free RMS on the same drive + 0.5 m), the first output
time ``t >= end`` of the fault from which every output error stays below the
threshold for at least ``RECOVERY_HOLD_S`` (5 s) -- or up to the end of the
drive, if that comes first -- minus the
fault's end. ``None`` (reported "never") when no such time exists; 0 when the
error never left the band; no verdict ("–") when the drive ends less than
``RECOVERY_HOLD_S`` after the fault.

Health checks: ``rate_kept`` -- every position finite, epochs strictly
increasing, and (fixed-rate estimators, finite ``rate_hz``) no gap longer than
1.5 output periods and at least 90 % of the fault-free number of outputs; per-scan
estimators (no fixed rate) keep at least 75 % of their fault-free outputs
outside the fault window. ``cov_pd`` -- every 2x2 position covariance
finite, symmetric (to 1e-9 relative) and with a positive smallest
eigenvalue (None when the estimator gives none). ``max_step_during_m`` -- the
largest change of the error between consecutive outputs inside the fault
window (a smooth growth keeps it small). Exceptions are caught per run and
reported with their type and message (and traceback in results.json).
"""

from __future__ import annotations

import json
import math
import time
import traceback
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from eval.execution import SimSource, executor, load_drive, provenance
from eval.report import Report, fmt, write_json
from graphpos.colors import color_of
from graphpos.drive import Drive
from graphpos.errors import ConfigError, GraphposError, MissingChannelError
from graphpos.io.outputs import atomic_output, output_folder
from graphpos.sim.faults import FAULTS

RECOVERY_FACTOR = 1.5
RECOVERY_MARGIN_M = 0.5
RECOVERY_HOLD_S = 5.0
#: Fault kinds acting on the whole drive (no "after", no recovery).
WHOLE_DRIVE = ("dead_tags", "clock_offset", "dropped_samples", "duplicated_samples", "late_readings")
#: Estimators drawn in the error-vs-time figure (those the study runs).
PLOTTED = ("dr", "fusion-ekf", "imm-stekf", "fkf", "graph-isam2", "graph-batch")
DEFAULT_SCENARIO = "paper-comprehensive"


# -- placing the faults ------------------------------------------------------------------------------------
def _stretch(t: np.ndarray, max_gap_s: float = 2.0) -> tuple[float, float] | None:
    """The longest run of samples at most ``max_gap_s`` apart."""
    if t.size < 2:
        return None
    breaks = np.flatnonzero(np.diff(t) > max_gap_s)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [t.size - 1]])
    i = int(np.argmax(t[ends] - t[starts]))
    return float(t[starts[i]]), float(t[ends[i]])


def _episode(kind: str, span: tuple[float, float]) -> dict[str, float]:
    length = span[1] - span[0]
    return {"start_s": round(span[0] + 0.25 * length, 3),
            "duration_s": round(min(FAULTS[kind]["duration_s"], 0.4 * length), 3)}


def study_faults(drive: Drive) -> dict[str, dict[str, Any] | str]:
    """Fault kind -> the spec the study injects, or the reason it does not apply (see the module doc)."""
    tunnel = drive.window("in_tunnel")
    in_tunnel = (tunnel[0].start_s, tunnel[0].end_s) if tunnel else (drive.start_s, drive.end_s)
    ranged = drive.has("rfid") or drive.has("rsu")
    out: dict[str, dict[str, Any] | str] = {}
    for kind in FAULTS:
        if kind in ("rfid_blackout", "nlos_burst", "late_readings") and not ranged:
            out[kind] = "the drive has no RFID or RSU readings"
        elif kind == "dead_tags" and not (drive.has("rfid") and len(drive.tags)):
            out[kind] = "the drive has no RFID tags"
        elif kind.startswith("gnss_"):
            stretch = _stretch(drive.gnss.t_s) if drive.has("gnss") else None
            out[kind] = _episode(kind, stretch) if stretch else "the drive has no GNSS fixes"
        elif kind in WHOLE_DRIVE:
            out[kind] = {}
            if kind == "clock_offset":
                channel = next((c for c in ("rfid", "rsu", "gnss") if drive.has(c)), "compass")
                out[kind] = {"channel": channel}
        else:
            out[kind] = _episode(kind, in_tunnel)
    return out


# -- one run -------------------------------------------------------------------------------------------------
def _cov_health(cov: np.ndarray | None) -> tuple[bool | None, float | None]:
    if cov is None:
        return None, None
    cov = np.asarray(cov, dtype=np.float64)
    if cov.size == 0:
        return True, None
    if not np.all(np.isfinite(cov)):
        return False, float("nan")
    scale = np.maximum(np.abs(cov).max(axis=(1, 2)), 1e-300)
    symmetric = np.all(np.abs(cov[:, 0, 1] - cov[:, 1, 0]) <= 1e-9 * scale)
    min_eig = float(np.linalg.eigvalsh(0.5 * (cov + np.transpose(cov, (0, 2, 1))))[:, 0].min())
    return bool(symmetric and min_eig > 0.0), min_eig


def run_one(source: SimSource, estimator: str) -> dict[str, Any]:
    """Run one estimator on one drive without its truth; the error series (against the truth) and health figures. Never raises."""
    from eval.metrics import interpolate_truth
    from graphpos.registry import make_estimator

    out: dict[str, Any] = {"error": None, "not_applicable": False}
    try:
        drive = load_drive(source)
        started = time.perf_counter()
        est = make_estimator(estimator).run(drive.without_truth())  # truth is for scoring only (issue 13)
        out["wall_time_s"] = time.perf_counter() - started
        truth = interpolate_truth(drive.truth, est.t_s)  # epochs outside the truth's span have no error
        err = np.hypot(est.east_m[truth.mask] - truth.east_m, est.north_m[truth.mask] - truth.north_m)
        out.update(t_s=est.t_s[truth.mask], error_m=err, output_t_s=est.t_s, rate_hz=float(est.rate_hz),
                   finite=bool(np.all(np.isfinite(est.east_m)) and np.all(np.isfinite(est.north_m))),
                   increasing=bool(np.all(np.diff(est.t_s) > 0)))
        out["cov_pd"], out["cov_min_eig_m2"] = _cov_health(est.cov_en_m2)
    except MissingChannelError as exc:
        out.update(error=str(exc), not_applicable=True)
    except GraphposError as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # a bug must be counted, not sink the study
        out.update(error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    return out


# -- figures -------------------------------------------------------------------------------------------------
def _stats(err: np.ndarray) -> tuple[float, float]:
    if err.size == 0:
        return float("nan"), float("nan")
    return float(err.max()), float(np.sqrt(np.mean(err**2)))


def recovery_time(t_s: np.ndarray, error_m: np.ndarray, end_s: float, threshold_m: float,
                  hold_s: float = RECOVERY_HOLD_S) -> float | None:
    """Seconds after ``end_s`` until the error stays below ``threshold_m`` for ``hold_s`` (see the module doc)."""
    after = t_s >= end_s
    t, bad = t_s[after], error_m[after] >= threshold_m
    if t.size == 0:
        return None
    # For each output, the time of the next output at or after it that is over the threshold (inf: none).
    bad_time = np.where(bad, t, np.inf)
    next_bad_s = np.minimum.accumulate(bad_time[::-1])[::-1]
    ok = ~bad & (next_bad_s - t >= hold_s)
    if not ok.any():
        return None
    return max(float(t[np.argmax(ok)] - end_s), 0.0)


def fault_figures(run: dict[str, Any], baseline: dict[str, Any], span: tuple[float, float] | None) -> dict[str, Any]:
    """Figures of one faulted run against the same estimator's fault-free run (see the module doc)."""
    t, err = np.asarray(run["t_s"]), np.asarray(run["error_m"])
    base_rms = _stats(np.asarray(baseline["error_m"]))[1]
    whole = span is None
    lo, hi = (-np.inf, np.inf) if whole else span
    during = (t >= lo) & (t <= hi)
    after = t > hi
    figs: dict[str, Any] = {"baseline_rms_m": base_rms}
    figs["during_max_m"], figs["during_rms_m"] = _stats(err[during])
    figs["after_max_m"], figs["after_rms_m"] = _stats(err[after])
    steps = np.abs(np.diff(err[during]))
    figs["max_step_during_m"] = float(steps.max()) if steps.size else float("nan")
    threshold = RECOVERY_FACTOR * base_rms + RECOVERY_MARGIN_M
    figs["recovery_threshold_m"] = threshold
    # Too little drive left after the fault to tell: no verdict (as for whole-drive faults).
    undecidable = whole or t.size == 0 or t[-1] - hi < RECOVERY_HOLD_S
    figs["recovery_s"] = None if undecidable else recovery_time(t, err, hi, threshold)
    figs["recovered"] = None if undecidable else figs["recovery_s"] is not None
    rate = run["rate_hz"]
    ot, bot = np.asarray(run["output_t_s"]), np.asarray(baseline["output_t_s"])
    kept = run["finite"] and run["increasing"]
    if math.isfinite(rate) and rate > 0:
        gaps = np.diff(ot)
        kept = kept and (gaps.size == 0 or gaps.max() <= 1.5 / rate) and ot.size >= 0.9 * bot.size
    else:
        outside = np.count_nonzero((ot < lo) | (ot > hi)) if not whole else ot.size
        b_outside = np.count_nonzero((bot < lo) | (bot > hi)) if not whole else bot.size
        kept = kept and outside >= 0.75 * b_outside
    figs["rate_kept"] = bool(kept)
    figs["cov_pd"] = run["cov_pd"]
    figs["cov_min_eig_m2"] = run["cov_min_eig_m2"]
    figs["n_outputs"], figs["n_outputs_fault_free"] = int(ot.size), int(bot.size)
    return figs


# -- the study -----------------------------------------------------------------------------------------------
@dataclass
class FaultStudy:
    """What :func:`fault_study` measured (also written to results.json)."""

    scenario: str
    estimators: list[str]
    seeds: int
    faults: dict[str, Any]
    #: (fault, estimator) -> one dict of figures per seed (or {"error": ...}).
    cells: dict[tuple[str, str], list[dict[str, Any]]] = field(default_factory=dict)
    wall_time_s: float = float("nan")

    @property
    def failures(self) -> list[tuple[str, str, str]]:
        """(fault, estimator, error) of every run that raised (not counting "not applicable")."""
        return [(f, e, c["error"]) for (f, e), cs in self.cells.items() for c in cs
                if c.get("error") and not c.get("not_applicable")]


def fault_source(scenario: str, seed: int, duration_s: float | None, fault: str | None, spec: Any) -> SimSource:
    """The simulation recipe of a drive with one fault (``fault`` None: fault-free)."""
    return SimSource(scenario, None, seed, duration_s=duration_s,
                     faults_json=json.dumps({fault: spec}, sort_keys=True) if fault else "")


def fault_span(drive: Drive, fault: str) -> tuple[float, float] | None:
    """The fault's episode on the drive; None for a whole-drive fault."""
    if fault in WHOLE_DRIVE:
        return None
    w = drive.window(f"fault:{fault}")[0]
    return (w.start_s, w.end_s)


def fault_study(scenario: str = DEFAULT_SCENARIO, estimators: list[str] | None = None, seeds: int = 2,
                duration_s: float | None = None, workers: int | None = None, progress: bool = True) -> FaultStudy:
    """Run every estimator on every fault (and fault-free) over ``seeds`` seeded drives.

    Returns the figures; :func:`write_study` writes them.

    Raises
    ------
    ConfigError
        Unknown scenario or estimator, or fewer than one seed.
    """
    from graphpos.registry import estimator_classes, require_known
    from graphpos.sim import SCENARIOS

    started = time.perf_counter()
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{scenario}' (known: {', '.join(SCENARIOS)})")
    if seeds < 1:
        raise ConfigError(f"--seeds must be at least 1, got {seeds}")
    names = list(estimators or estimator_classes())
    require_known(names)
    specs = study_faults(load_drive(fault_source(scenario, 0, duration_s, None, None)))
    applicable = [k for k, s in specs.items() if isinstance(s, dict)]
    jobs = [(seed, fault, est) for seed in range(seeds) for fault in [None, *applicable] for est in names]
    runs: dict[tuple[int, str | None, str], dict[str, Any]] = {}
    with executor(workers, tasks=len(jobs)) as pool:
        futures = {pool.submit(run_one, fault_source(scenario, seed, duration_s, fault, specs.get(fault)), est): (seed, fault, est)
                   for seed, fault, est in jobs}
        with tqdm(total=len(futures), desc="fault-study", unit="run", disable=not progress, leave=False) as bar:
            for fut in as_completed(futures):
                key = futures[fut]
                try:
                    runs[key] = fut.result()
                except Exception as exc:  # the worker process died
                    runs[key] = {"error": f"worker failed: {type(exc).__name__}: {exc}", "not_applicable": False}
                bar.update(1)
    study = FaultStudy(scenario, names, seeds, specs)
    for fault in [None, *applicable]:
        for est in names:
            cell = []
            for seed in range(seeds):
                run, base = runs[(seed, fault, est)], runs[(seed, None, est)]
                if run["error"] or base["error"]:
                    cell.append({k: v for k, v in (run if run["error"] else base).items() if k in ("error", "not_applicable", "traceback")})
                    continue
                span = None if fault is None else fault_span(load_drive(fault_source(scenario, seed, duration_s, fault, specs[fault])), fault)
                figs = fault_figures(run, base, span)
                figs["wall_time_s"] = run["wall_time_s"]
                if seed == 0 and est in PLOTTED:
                    figs["series"] = {"t_s": run["t_s"], "error_m": run["error_m"],
                                      "fault_free_error_m": base["error_m"], "fault_free_t_s": base["t_s"], "span": span}
                cell.append(figs)
            study.cells[(fault or "none", est)] = cell
    study.wall_time_s = time.perf_counter() - started
    return study


# -- the report ----------------------------------------------------------------------------------------------
def _mean(cell: list[dict[str, Any]], key: str) -> float:
    vals = [c[key] for c in cell if c.get(key) is not None and math.isfinite(c[key])]
    return float(np.mean(vals)) if vals else float("nan")


def _recovery_cell(cell: list[dict[str, Any]]) -> str:
    ok = [c for c in cell if "error" not in c]
    if not ok or ok[0]["recovered"] is None:
        return "–"
    if any(not c["recovered"] for c in ok):
        return "never"
    return fmt(max(c["recovery_s"] for c in ok), 1)


def summary_cell(cell: list[dict[str, Any]]) -> str:
    """``max/RMS during (recovery s)``, means over seeds, worst recovery; "n/a" or "FAILED"."""
    if all("error" in c for c in cell):
        return "n/a" if all(c.get("not_applicable") for c in cell) else "FAILED"
    text = f"{fmt(_mean(cell, 'during_max_m'), 1)}/{fmt(_mean(cell, 'during_rms_m'), 1)}"
    rec = _recovery_cell(cell)
    return text if rec == "–" else f"{text} ({rec})"


def _figure(study: FaultStudy, folder: Path) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodic = [f for f, s in study.faults.items() if isinstance(s, dict) and f not in WHOLE_DRIVE]
    shown = [e for e in PLOTTED if e in study.estimators]
    if not episodic or not shown:
        return None
    cols = 2
    rows = math.ceil(len(episodic) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(12, 3.2 * rows), squeeze=False)
    for ax, fault in zip(axes.flat, episodic):
        span = None
        for est in shown:
            c = study.cells.get((fault, est), [{}])[0]
            s = c.get("series")
            if not s:
                continue
            span = s["span"]
            ax.plot(s["t_s"], s["error_m"], color=color_of(est), lw=1.0, label=est)
            ax.plot(s["fault_free_t_s"], s["fault_free_error_m"], color=color_of(est), lw=0.7, ls=":")
        if span:
            ax.axvspan(*span, color="0.85", lw=0, label="fault")
            width = span[1] - span[0]
            ax.set_xlim(span[0] - max(10.0, 0.5 * width), span[1] + max(30.0, width))
        ax.set_title(f"{fault} (dotted: fault-free)", fontsize=10)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("error [m]")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(episodic):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, ncol=2)
    fig.suptitle(f"{study.scenario}, seed 0: position error around each fault")
    fig.tight_layout()
    path = folder / "fault_errors.png"
    with atomic_output(path) as stream:
        fig.savefig(stream, format="png", dpi=100)
    plt.close(fig)
    return path


def _jsonable_cell(c: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in c.items() if k != "series"}


def write_study(study: FaultStudy, folder: Path) -> Path:
    """Write ``results.json``, ``report.md``/``report.html`` and ``fault_errors.png`` into ``folder``."""
    folder = Path(folder)
    with output_folder(folder, "results.json") as out:
        faults = ["none", *[f for f, s in study.faults.items() if isinstance(s, dict)]]
        report = Report(f"graphpos fault-study — {study.scenario}")
        sec = report.section("Position error during each fault and recovery after it")
        sec.text(f"{study.seeds} seed(s); every estimator with its defaults on the same drives. Cell: max/RMS error "
                 "during the fault, metres (means over seeds), and in brackets the recovery time after the fault's end, "
                 f"seconds (worst over seeds): until the error stays under {RECOVERY_FACTOR} x the estimator's fault-free "
                 f"RMS + {RECOVERY_MARGIN_M} m for {RECOVERY_HOLD_S:.0f} s. 'never': not within the drive. Whole-drive "
                 "faults have no recovery. Row 'none': the fault-free drive (whole-drive max/RMS). n/a: the estimator "
                 "needs a channel the scenario lacks.")
        sec.table(["fault"] + study.estimators,
                  [[f] + [summary_cell(study.cells[(f, e)]) for e in study.estimators] for f in faults])
        health = report.section("Health: output rate, covariance, exceptions")
        rows = []
        for f in faults:
            for e in study.estimators:
                ok = [c for c in study.cells[(f, e)] if "error" not in c]
                errors = [c["error"] for c in study.cells[(f, e)] if "error" in c and not c.get("not_applicable")]
                if not ok and not errors:
                    continue
                bad_rate = sum(not c["rate_kept"] for c in ok)
                bad_cov = sum(c["cov_pd"] is False for c in ok)
                if bad_rate or bad_cov or errors:
                    rows.append([f, e, str(bad_rate), str(bad_cov), "; ".join(errors)[:160]])
        if rows:
            health.table(["fault", "estimator", "rate lost (runs)", "covariance not PD (runs)", "exception"], rows)
        else:
            health.text("Every run kept its output rate, every covariance given stayed positive definite, "
                        "and no run raised.")
        details = report.section("Details per fault and estimator")
        details.text("Means over seeds (recovery: worst). 'after': from the fault's end to the end of the drive.")
        rows = []
        for f in faults[1:]:
            for e in study.estimators:
                cell = study.cells[(f, e)]
                if all("error" in c for c in cell):
                    continue
                rows.append([f, e] + [fmt(_mean(cell, key)) for key in
                                      ("baseline_rms_m", "during_max_m", "during_rms_m", "after_max_m", "after_rms_m")]
                            + [_recovery_cell(cell)])
        details.table(["fault", "estimator", "fault-free RMS", "during max", "during RMS", "after max", "after RMS",
                       "recovery [s]"], rows)
        placed = report.section("Where the faults were placed")
        placed.table(["fault", "spec (or why not applicable)"],
                     [[f, json.dumps(s) if isinstance(s, dict) else s] for f, s in study.faults.items()])
        png = _figure(study, out)
        if png:
            report.section("Error around each fault").figure(
                png, "One drive per fault: seed 0 (the tables average every seed).")
        report.section("Run").text(f"{sum(len(c) for c in study.cells.values())} runs in {study.wall_time_s:.0f} s.")
        write_json(out / "results.json", {
            "command": "fault-study", "scenario": study.scenario, "seeds": study.seeds,
            "estimators": study.estimators, "faults": study.faults, "wall_time_s": study.wall_time_s,
            "recovery": {"factor": RECOVERY_FACTOR, "margin_m": RECOVERY_MARGIN_M, "hold_s": RECOVERY_HOLD_S},
            "provenance": provenance(),
            "cells": [{"fault": f, "estimator": e, "seeds": [_jsonable_cell(c) for c in cs]}
                      for (f, e), cs in study.cells.items()],
        })
        report.write(out)
    return folder
