"""``graphpos reproduce``: the papers' tables rebuilt on simulated drives, ours beside theirs.

Every (drive, estimator, layout) run is done once, even when several tables
use it, and all runs go to the executor together. Each table cell is the mean
± STD over seeds of the figure the paper reports. A run that fails shows
``FAILED: <reason>`` in its cell, is listed in a Failures section and in
``results.json``; one where the estimator refuses the drive for a missing
channel shows ``n/a``.

Beside the tables: a summary (the papers' most accurate filter against each
factor graph, per table), the speed error of song2016 Fig. 16, and the
late-measurement and fault studies (:data:`DEGRADED`) on the straight test.
``--quick`` runs 2 seeds, two of the seven Table 4 patterns, one seed of the
degraded-data studies and the first 180 s of Plaza.

Real data: when the Plaza file is present, the estimators that can use its
sensors (UWB ranges, wheel odometry, gyro; no accelerometers, no compass) run
on it. The ranging is not calibrated on the evaluated drive's truth: Plaza1
is the only Plaza drive available, so the range model is a self-calibration
on the drive without its truth (:func:`graphpos.graph.calibration.calibrate_range_scale`:
the radio's common range scale and a robust sigma from graph-batch's
solution).

Truth is for scoring only (issue 13): every run hands its estimator the
drive without its truth (:func:`eval.execution.run_job`) and scores the
output against the full drive afterwards.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from eval import plots
from eval.evaluate import Outcome, add_failure_section, cell_error, result_record
from eval.execution import Job, JobResult, SimSource, execute, load_drive, provenance
from eval.experiments import GRAPH_ESTIMATORS, LIU2016_BOUND_M, Experiment, experiments
from eval.metrics import WHOLE
from eval.report import Report, fmt, mean_spread, write_json
from graphpos.drive import Drive, Window
from graphpos.io.outputs import output_folder, safe_name

#: Seeds per experiment.
SEEDS_FULL = 5
SEEDS_QUICK = 2
#: song2016 Table 4 patterns run by --quick (one constant-angular-velocity curve, one lane change).
QUICK_TABLE4 = ("constant", "lane-change-curve")
#: Late-measurement and fault studies on the straight test: label -> (RFID latency range in s, faults
#: JSON for graphpos.sim.faults). Episodes start 30 % into the drive (the simulator's default), inside
#: the tunnel.
DEGRADED = {
    "nominal": (None, ""),
    "RFID 0.5–2 s late": ((0.5, 2.0), ""),
    "RFID blackout 20 s": (None, '{"rfid_blackout": {"duration_s": 20.0}}'),
    "30 % dead tags": (None, '{"dead_tags": {"fraction": 0.3}}'),
    "NLOS burst": (None, '{"nlos_burst": {}}'),
    "wheel slip": (None, '{"wheel_slip": {}}'),
}
DEGRADED_ESTIMATORS = (("fusion-ekf", "dense"), ("fukf", "optimized"), ("graph-batch", "dense"), ("graph-isam2", "dense"))

_RunKey = tuple  # (SimSource or "plaza", estimator, layout)


def default_plaza_path() -> Path:
    """``<repo>/../shared/data/plaza/Plaza1.mat``."""
    return Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "plaza" / "Plaza1.mat"


#: --quick scores the first this many seconds of Plaza (the whole 32-minute drive otherwise).
QUICK_PLAZA_S = 180.0

#: Estimators tried on Plaza (those lacking a sensor Plaza does not have report n/a).
PLAZA_ESTIMATORS = ("multilateration", "rfid-ekf", "dr", "fusion-ekf", "fukf", "two-level-ekf", *GRAPH_ESTIMATORS)


class _Runs:
    """Deduplicated jobs: one per (source, estimator, layout)."""

    def __init__(self) -> None:
        self.jobs: dict[_RunKey, Job] = {}

    def add(self, source: Any, estimator: str, layout: str | None, keep: bool = False,
            range_model: Any = None) -> _RunKey:
        key = (source if isinstance(source, SimSource) else "plaza", estimator, layout)
        old = self.jobs.get(key)
        if old is None or (keep and not old.keep_estimate):
            self.jobs[key] = Job(source, estimator, layout=layout, keep_estimate=keep, range_model=range_model)
        return key


def first_seconds(drive: Drive, seconds: float) -> Drive:
    """The first ``seconds`` of a drive (every channel cut at the same time; windows clipped)."""
    end = drive.start_s + seconds
    windows = [Window(w.label, w.start_s, min(w.end_s, end)) for w in drive.windows if w.start_s <= end]
    return drive.replace(name=f"{drive.name}-first{seconds:.0f}s",
                         channels={k: ch.between(drive.start_s, end) for k, ch in drive.channels.items()},
                         windows=tuple(windows), params={**drive.params, "cut_after_s": seconds})


def window_stat(r: JobResult, window: str, stat: str) -> float:
    """One position statistic of a run in a window (NaN when the run failed or lacks the window)."""
    if not r.ok:
        return math.nan
    w = r.metrics["windows"].get(window)
    return w["position"][stat] if w else math.nan


def seeds_cell(results: list[JobResult], window: str, stat: str) -> str:
    """Mean ± STD over seeds, or why there is no figure."""
    good = [r for r in results if r.ok]
    if not good:
        return cell_error(results[0]) if results else "–"
    text = mean_spread([window_stat(r, window, stat) for r in good])
    failed = len(results) - len(good)
    return text + (f" ({failed} of {len(results)} runs failed)" if failed else "")


def _run_info(results: list[JobResult]) -> tuple[str, str]:
    good = [r for r in results if r.ok]
    if not good:
        return "–", "–"
    return fmt(np.median([r.metrics["output_rate_hz"] for r in good]), 1), fmt(good[0].metrics["velocity_provided"])


def _experiment_table(exp: Experiment, res: dict[_RunKey, JobResult], sources: list[SimSource]) -> tuple[list[str], list[list[str]], list[dict]]:
    """Header, rows and the JSON record of one max/RMS table."""
    header = ["estimator", "layout", "paper max", "paper RMS", "ours max", "ours RMS"]
    in_tunnel_col = exp.window == WHOLE
    if in_tunnel_col:
        header.append("ours RMS in tunnel")
    header += ["rate [Hz]", "velocity", "wall [s]"]
    rows, records = [], []
    for row in exp.all_rows():
        rs = [res[(s, row.estimator, row.layout)] for s in sources]
        pub = row.published or (math.nan, math.nan)
        line = [row.label, row.layout or "–", fmt(pub[0]), fmt(pub[1]), seeds_cell(rs, exp.window, "max_m"),
                seeds_cell(rs, exp.window, "rms_m")]
        if in_tunnel_col:
            line.append(seeds_cell(rs, "in_tunnel", "rms_m"))
        rate, velocity = _run_info(rs)
        wall = [r.metrics["wall_time_s"] for r in rs if r.ok]
        line += [rate, velocity, mean_spread(wall)]
        rows.append(line)
        records.append({
            "estimator": row.estimator, "label": row.label, "layout": row.layout, "published_max_rms_m": row.published,
            "max_m": [window_stat(r, exp.window, "max_m") for r in rs],
            "rms_m": [window_stat(r, exp.window, "rms_m") for r in rs],
            "errors": [r.error for r in rs],
        })
    return header, rows, records


def _zones_table(exp: Experiment, res: dict[_RunKey, JobResult], sources: list[SimSource]) -> tuple[list[str], list[list[str]], list[dict]]:
    """liu2016: 2DRMS per zone window."""
    zones: list[str] = []
    for row in exp.all_rows():
        for s in sources:
            r = res[(s, row.estimator, row.layout)]
            if r.ok:
                zones += [w for w in r.metrics["windows"] if w.startswith("zone:") and w not in zones]
    def zone_header(zone: str) -> str:
        bound = LIU2016_BOUND_M.get(zone[len("zone:"):])
        return f"2DRMS {zone[len('zone:'):]} [m] " + (f"(paper ≤ {bound:.1f})" if bound else "(paper: no figure)")

    header = ["estimator"] + [zone_header(z) for z in zones] + [f"2DRMS {WHOLE} [m]"]
    rows, records = [], []
    for row in exp.all_rows():
        rs = [res[(s, row.estimator, row.layout)] for s in sources]
        rows.append([row.label] + [seeds_cell(rs, z, "drms2_m") for z in zones] + [seeds_cell(rs, WHOLE, "drms2_m")])
        records.append({"estimator": row.estimator, "drms2_m": {z: [window_stat(r, z, "drms2_m") for r in rs] for z in zones + [WHOLE]},
                        "errors": [r.error for r in rs]})
    return header, rows, records


#: Column titles of the figures graphpos.ranging.table1 returns (distance errors in m, RSS errors in 0-255 units).
_TABLE1_COLUMNS = {"mean": "ours mean [m]", "std": "ours STD [m]", "rms": "ours RMS [m]",
                   "rss_mean": "ours mean [RSS]", "rss_std": "ours STD [RSS]"}


def _table1(seeds: int) -> tuple[list[str], list[list[str]], dict]:
    """song2016 Table 1 from :mod:`graphpos.ranging.table1`, over calibration seeds."""
    from graphpos.ranging.drive_models import CALIBRATION_SEED
    from graphpos.ranging.table1 import PUBLISHED_TABLE1, table1

    runs = [table1(CALIBRATION_SEED + k) for k in range(seeds)]
    keys = list(next(iter(next(iter(runs[0].values())).values())))
    header = ["environment", "model", "paper mean", "paper STD"] + [_TABLE1_COLUMNS.get(k, f"ours {k}") for k in keys]
    rows = []
    for env, models in runs[0].items():
        for kind in models:
            pub = PUBLISHED_TABLE1.get(env, {}).get(kind, (math.nan, math.nan))
            rows.append([env, kind, fmt(pub[0]), fmt(pub[1])] + [mean_spread([r[env][kind][k] for r in runs]) for k in keys])
    return header, rows, {"seeds": [CALIBRATION_SEED + k for k in range(seeds)], "figures": runs}


def reproduce(folder: Path, quick: bool = False, seeds: int | None = None, plaza: Path | None = None,
              workers: int | None = None, scheduler: str | None = None, progress: bool = True) -> Outcome:
    """Run every experiment and write the reproduction folder (see the module docstring)."""
    from graphpos.errors import ConfigError

    started = time.perf_counter()
    folder = Path(folder)
    n_seeds = seeds if seeds is not None else (SEEDS_QUICK if quick else SEEDS_FULL)
    if n_seeds < 1:
        raise ConfigError(f"--seeds must be at least 1, got {n_seeds}")
    exps = [e for e in experiments()
            if not (quick and e.key.startswith("song2016-table4/") and e.pattern not in QUICK_TABLE4)]
    plaza_path = plaza if plaza is not None else default_plaza_path()

    runs = _Runs()
    sources: dict[str, list[SimSource]] = {}
    for exp in exps:
        sources[exp.key] = [SimSource(exp.scenario, exp.pattern, seed, overrides_json=exp.overrides_json)
                            for seed in range(n_seeds)]
        for seed, src in enumerate(sources[exp.key]):
            for row in exp.all_rows():
                runs.add(src, row.estimator, row.layout, keep=seed == 0)
    degraded_seeds = 1 if quick else n_seeds
    degraded = {label: [SimSource("paper-straight", None, seed, rfid_latency_s=late, faults_json=faults)
                        for seed in range(degraded_seeds)] for label, (late, faults) in DEGRADED.items()}
    for srcs in degraded.values():
        for src in srcs:
            for name, layout in DEGRADED_ESTIMATORS:
                runs.add(src, name, layout)
    plaza_drive = None
    if plaza is not None or plaza_path.is_file():  # a given file must import (clear errors)
        from graphpos.graph.calibration import calibrate_range_scale
        from graphpos.io.plaza import import_plaza

        plaza_drive = import_plaza(plaza_path)
        if quick:
            plaza_drive = first_seconds(plaza_drive, QUICK_PLAZA_S)
        # Self-calibrated on the drive itself, without its truth (the only
        # Plaza drive: no other drive to fit a calibration on).
        plaza_model = calibrate_range_scale(plaza_drive.without_truth())
        plaza_drive = plaza_drive.replace(params={**plaza_drive.params, "range_model": plaza_model.to_dict()})
        for name in PLAZA_ESTIMATORS:
            runs.add(plaza_drive, name, None, keep=True, range_model=plaza_model)

    with output_folder(folder, "results.json") as out:
        keys = list(runs.jobs)
        results = execute([runs.jobs[k] for k in keys], workers=workers, scheduler=scheduler, progress=progress,
                          desc="reproduce")
        res = dict(zip(keys, results))

        report = Report("graphpos reproduce — the papers' tables on simulated drives" + (" (quick)" if quick else ""))
        report.section("How to read this").text(
            f"Each cell is the mean ± STD over {n_seeds} seed(s) of simulated drives built to the paper's "
            "specification (graphpos.sim scenarios); 'paper' columns are the published single-test figures. Errors "
            "are Euclidean 2-D position errors in metres against the simulated truth, absolute (no alignment). "
            "The factor-graph estimators (graph-*) are extra rows: the papers have no such figures. "
            "FAILED cells name the error; n/a means the estimator lacks a sensor the drive does not carry."
        )
        summary = report.section("Summary: the papers' best filter against the factor graphs")
        tables: dict[str, Any] = {}

        header, rows, record = _table1(n_seeds)
        report.section("song2016 Table 1 — RSS to distance fitting errors").table(header, rows).text(
            "From graphpos.ranging.table1: held-out readings of simulated calibration collections, mean ± STD over "
            "calibration seeds. The paper does not define its 'fitting error' or its unit; ours is given both as a "
            "distance error [m] and as an RSS error [0-255 units] (see that module's docstring)."
        )
        tables["song2016-table1"] = record

        plotted: set = set()
        for exp in exps:
            srcs = sources[exp.key]
            sec = report.section(exp.title)
            sec.text(f"Scenario {exp.scenario}" + (f", pattern {exp.pattern}" if exp.pattern else "")
                     + f"; window: {exp.window}." + (f" {exp.note}" if exp.note else ""))
            make = _zones_table if exp.metric == "drms2_zones" else _experiment_table
            header, rows, record = make(exp, res, srcs)
            sec.table(header, rows)
            tables[exp.key] = {"title": exp.title, "scenario": exp.scenario, "pattern": exp.pattern,
                               "window": exp.window, "seeds": list(range(n_seeds)), "rows": record}
            first = srcs[0]
            plot_key = (first, tuple((r.estimator, r.layout) for r in exp.all_rows()))
            if plot_key not in plotted:  # song2014 Tables 4 and 5/6 show the same runs in two windows
                plotted.add(plot_key)
                estimates = [res[(first, r.estimator, r.layout)].estimate for r in exp.all_rows()
                             if res[(first, r.estimator, r.layout)].ok and len(res[(first, r.estimator, r.layout)].estimate)]
                if estimates:
                    drive = load_drive(first)
                    sub = out / safe_name(exp.key)
                    sec.figure(plots.trajectories(drive, estimates, sub / "trajectories.png"))
                    sec.figure(plots.error_vs_time(drive, estimates, sub / "error_vs_time.png"))
                    if exp.key == "song2016-table3":
                        speed = plots.speed_error(drive, estimates, sub / "speed_error.png")
                        if speed:
                            sec.figure(speed)

        _fill_summary(summary, [e for e in exps if e.metric == "max_rms"], res, sources)
        _speed_section(report, res, sources.get("song2016-table3", []), tables)
        _degraded_section(report, res, degraded, tables)
        if plaza_drive is not None:
            _plaza_section(report, res, plaza_drive, out, tables)
        else:
            report.section("Real data (Plaza)").text(f"Skipped: {plaza_path} not found (give --plaza FILE.mat).")

        add_failure_section(report, results)
        took = time.perf_counter() - started
        busy = sum(r.metrics["wall_time_s"] for r in results if r.ok)
        report.section("Run").text(f"{len(results)} runs ({len(results) - sum(r.ok for r in results)} without figures) "
                                   f"in {took:.0f} s of wall time ({busy:.0f} s inside the estimators, summed over "
                                   f"workers); seeds {n_seeds}; quick={quick}.")
        write_json(out / "results.json", {
            "command": "reproduce", "quick": quick, "seeds": n_seeds, "wall_time_s": took,
            "provenance": provenance(), "tables": tables, "runs": [result_record(r) for r in results],
        })
        report.write(out)
    return Outcome(results, folder)


def _fill_summary(sec, exps: list[Experiment], res: dict, sources: dict[str, list[SimSource]]) -> None:
    """Per table: ours for the paper's most accurate estimator beside each graph estimator (RMS, table's window)."""
    rows = []
    for exp in exps:
        def mean_rms(row) -> float:
            vals = [window_stat(res[(s, row.estimator, row.layout)], exp.window, "rms_m") for s in sources[exp.key]]
            vals = [v for v in vals if np.isfinite(v)]
            return float(np.mean(vals)) if vals else math.nan

        paper_rows = [(mean_rms(r), r) for r in exp.rows]
        ranked = sorted((v, r.label) for v, r in paper_rows if np.isfinite(v))
        best = f"{ranked[0][1]}: {ranked[0][0]:.2f}" if ranked else "–"
        extra = {r.estimator: r for r in exp.all_rows()[len(exp.rows):]}
        graphs = [fmt(mean_rms(extra[g])) if g in extra else "–" for g in GRAPH_ESTIMATORS]
        rows.append([exp.title, exp.window, best, *graphs])
    sec.text("RMS error in metres (mean over seeds) in each table's window: the most accurate of the paper's "
             "estimators on our drives, and each factor-graph estimator on the same drives.")
    sec.table(["table", "window", "best paper estimator (ours)", *GRAPH_ESTIMATORS], rows)


def _speed_section(report: Report, res: dict, srcs: list[SimSource], tables: dict) -> None:
    """song2016 Fig. 16: speed error of the estimators with velocity, beside the raw wheel speed."""
    if not srcs:
        return
    by_name: dict[str, list[JobResult]] = defaultdict(list)
    for (src, name, _layout), r in res.items():
        if src in srcs and r.ok and r.metrics["velocity_provided"]:
            by_name[name].append(r)
    if not by_name:
        return
    wheel = [r.metrics["windows"][WHOLE]["wheel_speed"] for rs in by_name.values() for r in rs[:1]]
    rows = [["raw wheel speed", mean_spread([w["mean_mps"] for w in wheel if w], 3),
             mean_spread([w["rms_mps"] for w in wheel if w], 3)]]
    for name, rs in by_name.items():
        sp = [r.metrics["windows"][WHOLE]["speed"] for r in rs]
        rows.append([name, mean_spread([s["mean_mps"] for s in sp], 3), mean_spread([s["rms_mps"] for s in sp], 3)])
    report.section("Speed error against truth (song2016 Fig. 16), straight test").table(
        ["source", "mean [m/s]", "RMS [m/s]"], rows)
    tables["song2016-fig16"] = {"rows": rows}


def _degraded_section(report: Report, res: dict, degraded: dict[str, list[SimSource]], tables: dict) -> None:
    """Late readings and injected faults against the nominal drives (same seeds), and the error inside each fault."""
    rows, fault_rows, record = [], [], []
    for name, layout in DEGRADED_ESTIMATORS:
        row = [name, layout]
        for label, srcs in degraded.items():
            rs = [res[(s, name, layout)] for s in srcs]
            row.append(seeds_cell(rs, "in_tunnel", "rms_m"))
            entry = {"estimator": name, "variant": label, "rms_in_tunnel_m": [window_stat(r, "in_tunnel", "rms_m") for r in rs]}
            for window in sorted({w for r in rs if r.ok for w in r.metrics["windows"] if w.startswith("fault:")}):
                fault_rows.append([label, name, window, seeds_cell(rs, window, "max_m"), seeds_cell(rs, window, "rms_m"),
                                   seeds_cell(rs, "in_tunnel", "rms_m")])
                entry[f"rms_in_{window}_m"] = [window_stat(r, window, "rms_m") for r in rs]
            record.append(entry)
        rows.append(row)
    sec = report.section("Late measurements and faults (paper-straight, RMS in the tunnel)")
    sec.table(["estimator", "layout", *degraded], rows).text(
        "Same drives (seeds) in every column. Late: RFID readings arrive 0.5–2 s after they were taken; a filter "
        "processing in arrival order sees old readings, a graph attaches them to the keyframe of their own "
        "timestamp. Faults from graphpos.sim.faults, one episode 30 % into the drive (dead tags: the whole drive).")
    if fault_rows:
        sec.table(["fault", "estimator", "window", "max in fault [m]", "RMS in fault [m]", "RMS in tunnel [m]"],
                  sorted(fault_rows, key=lambda r: (r[0], r[1])), caption="Error inside each fault window")
    tables["degraded"] = record


def _plaza_section(report: Report, res: dict, drive, folder: Path, tables: dict) -> None:
    rs = {name: res[("plaza", name, None)] for name in PLAZA_ESTIMATORS}
    header = ["estimator", "max [m]", "RMS [m]", "mean [m]", "p95 [m]", "scored / outputs", "rate [Hz]", "wall [s]"]
    rows = []
    for name, r in rs.items():
        if not r.ok:
            rows.append([name, cell_error(r)] + [""] * (len(header) - 2))
            continue
        p = r.metrics["windows"][WHOLE]["position"]
        rows.append([name, fmt(p["max_m"]), fmt(p["rms_m"]), fmt(p["mean_m"]), fmt(p["p95_m"]),
                     f"{p['n']} / {r.metrics['n_outputs']}", fmt(r.metrics["output_rate_hz"], 1),
                     fmt(r.metrics["wall_time_s"])])
    sec = report.section(f"Real data: Plaza ({drive.name})")
    sec.text(f"{drive.duration_s:.0f} s of driving: UWB ranges to beacons, wheel odometry and gyro; ground truth "
             "from the dataset. Every estimator uses one range calibration, self-calibrated from the drive "
             "without its truth (graphpos.graph.calibrate_range_scale: range scale "
             f"{drive.params['range_model']['scale']:.4f}, sigma {drive.params['range_model']['sigma0_m']:.2f} m). "
             "One drive, so no spread."
             + (" --quick scores only the first minutes." if "cut_after_s" in drive.params else ""))
    sec.table(header, rows)
    estimates = [r.estimate for r in rs.values() if r.ok and len(r.estimate)]  # not the ones that never started
    if estimates:
        sec.figure(plots.trajectories(drive, estimates, folder / "plaza" / "trajectories.png"))
        sec.figure(plots.error_vs_time(drive, estimates, folder / "plaza" / "error_vs_time.png"))
    tables["plaza"] = {"rows": rows}

