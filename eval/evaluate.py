"""``graphpos evaluate``: estimators over recorded drives, scored and reported.

Output folder layout::

    results.json              every figure + provenance (versions, configs, drives)
    report.md, report.html    tables and plots (the HTML embeds the plots)
    <drive>/trajectories.png, error_vs_time.png, error_cdf.png, speed_error.png
    <drive>/bound_vs_time.png  the position bound along the drive beside the errors
    <drive>/<estimator>.tum|.kml|.geojson|.csv   per-estimator exports
    <drive>/truth.tum|.kml|.geojson|.csv         the truth's (evo_ape tum truth.tum <estimator>.tum)
    <drive>/all_estimates.kml  every track in one Google Earth file
    <drive>/estimates.mcap     the drive, its truth and every estimate (Foxglove)
    <drive>/estimates_ros2/    a ROS 2 bag: every estimate and the truth as nav_msgs/Odometry

The files of ``<drive>/`` but the plots are :func:`graphpos.io.exports.write_exports`,
the same as ``graphpos run`` writes.

``<drive>`` and ``<estimator>`` are the names made file-safe
(:func:`graphpos.io.outputs.safe_name`); two drives of one name get
``<drive>-2`` and so on. The folder is written by
:func:`graphpos.io.outputs.output_folder`: complete or absent.

Each drive's tables hold the posterior Cramer-Rao bound on the position
error (:mod:`eval.bounds`, issue 18): a row per bound (smoother, filtering)
and each estimator's efficiency (its RMS over its matching bound's RMS);
results.json holds them per drive (``drives[i].bound``).

Truth is for scoring only (issue 13): the workers hand every estimator the
drive without its truth (:meth:`graphpos.drive.Drive.without_truth`) and
score its output against the full drive afterwards
(:func:`eval.execution.run_job`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eval import plots
from eval.bounds import BOUND_LABELS, NO_BOUND, DriveBound, bound_kind, bound_label, drive_bounds, result_efficiency
from eval.execution import FileSource, Job, JobResult, describe_source, execute, failures, provenance
from eval.metrics import WHOLE
from eval.names import same_windows, window_name
from eval.report import Report, Section, fmt, write_json
from graphpos.drive import Drive
from graphpos.errors import ConfigError, MissingChannelError, naming_file
from graphpos.io import read_drive
from graphpos.io.checks import drive_checks
from graphpos.io.exports import write_exports
from graphpos.io.outputs import output_folder, safe_name
from graphpos.registry import start_pose_record


@dataclass
class Outcome:
    """What a report command produced."""

    results: list[JobResult]
    folder: Path

    @property
    def failures(self) -> list[JobResult]:
        return failures(self.results)


def require_truth(drive: Drive) -> None:
    if not drive.has("truth"):
        raise MissingChannelError(f"evaluate needs truth: drive '{drive.name}' has no truth channel")


#: Under this share of the drive's truth covered by its outputs (:func:`eval.metrics.coverage`), a run's figures are
#: flagged as over part of the drive.
MIN_COVERAGE = 0.9


def run_warnings(r: JobResult) -> list[str]:
    """What an estimator said of its run (``diagnostics["warnings"]``: e.g. a drive too short to calibrate the noise on),
    and whether its outputs cover less than :data:`MIN_COVERAGE` of the drive (its figures are over that part only)."""
    metrics = r.metrics or {}
    lines = list((metrics.get("diagnostics") or {}).get("warnings", []))
    whole = (metrics.get("windows") or {}).get("whole") or {}
    share = whole.get("coverage")
    if share is not None and not math.isnan(share) and share < MIN_COVERAGE:
        why = (metrics.get("diagnostics") or {}).get("not_started")
        lines.append(f"its outputs cover {100 * share:.0f} % of the drive's truth span, and its figures are over that part only"
                     + (f" ({why})" if why and share == 0 else " (a late start, a track that ended early, or gaps: see its diagnostics)"))
    return lines


def result_record(r: JobResult) -> dict[str, Any]:
    """One result as stored in results.json."""
    return {
        "drive": r.drive_name,
        "source": describe_source(r.job.source),
        "drive_params": r.drive_params,
        "estimator": r.job.estimator,
        "layout": r.job.layout,
        "range_model": r.job.range_model if isinstance(r.job.range_model, (str, type(None))) else repr(r.job.range_model),
        "tag": r.job.tag,
        "settings": r.job.settings,
        "initial_pose": start_pose_record(r.job.initial_pose),
        "start": (r.metrics or {}).get("diagnostics", {}).get("start"),
        "config": r.config,
        "metrics": r.metrics,
        "error": r.error,
        "not_applicable": r.not_applicable,
        "traceback": r.traceback,
    }


def cell_error(r: JobResult, width: int = 90) -> str:
    """What a table cell says for a run that gave no figures (the full message is in Failures and results.json)."""
    text = f"n/a: {r.error}" if r.not_applicable else f"FAILED: {r.error}"
    return text if len(text) <= width else text[: width - 1] + "…"


def window_table(results: list[JobResult], window: str) -> tuple[list[str], list[list[str]]]:
    """Accuracy, speed and consistency of each estimator in one window."""
    header = ["estimator", "max [m]", "RMS [m]", "mean [m]", "median [m]", "p95 [m]", "2DRMS [m]",
              "east mean/STD [m]", "north mean/STD [m]", "speed err RMS [m/s]", "ANEES (95 % band)", "rate [Hz]",
              "velocity", "wall [s]", "RTF"]
    rows = []
    for r in results:
        if not r.ok:
            rows.append([r.job.estimator, cell_error(r)] + [""] * (len(header) - 2))
            continue
        not_started = (r.metrics.get("diagnostics") or {}).get("not_started")
        if not_started and r.metrics["n_outputs"] == 0:
            rows.append([r.job.estimator, f"not started: {not_started}"] + [""] * (len(header) - 2))
            continue
        w = r.metrics["windows"].get(window)
        if w is None:
            continue
        p, s, q = w["position"], w["speed"], w["nees"]
        anees = "–" if q is None else f"{fmt(q['anees'])} ({fmt(q['band'][0])}–{fmt(q['band'][1])})"
        rows.append([
            r.job.estimator, fmt(p["max_m"]), fmt(p["rms_m"]), fmt(p["mean_m"]), fmt(p["median_m"]), fmt(p["p95_m"]),
            fmt(p["drms2_m"]), f"{fmt(p['east_mean_m'])} / {fmt(p['east_std_m'])}",
            f"{fmt(p['north_mean_m'])} / {fmt(p['north_std_m'])}", fmt(s["rms_mps"]) if s else "–", anees,
            fmt(r.metrics["output_rate_hz"], 1), fmt(r.metrics["velocity_provided"]),
            fmt(r.metrics["wall_time_s"]), fmt(r.metrics["real_time_factor"], 3),
        ])
    return header, rows


def wheel_line(results: list[JobResult], window: str) -> str | None:
    """The raw wheel-speed error of a window (the same for every estimator of a drive)."""
    for r in results:
        if r.ok and r.metrics["windows"].get(window, {}).get("wheel_speed"):
            w = r.metrics["windows"][window]["wheel_speed"]
            return f"Raw wheel-speed error in this window: mean {fmt(w['mean_mps'])} m/s, RMS {fmt(w['rms_mps'])} m/s."
    return None


def with_bound(header: list[str], rows: list[list[str]], results: list[JobResult], window: str,
               bound: DriveBound) -> tuple[list[str], list[list[str]]]:
    """A :func:`window_table` with the position bound: an efficiency column (each estimator's RMS over its
    matching bound's RMS, :func:`eval.bounds.bound_kind`) and one row per bound (its RMS in the RMS column,
    or "— (why)" where there is no bound)."""
    by_name = {r.job.estimator: r for r in results}
    out = []
    for row in rows:
        r = by_name.get(row[0])
        eff = result_efficiency(r, bound, window) if r is not None else math.nan
        label = bound_label(row[0]) + ("" if bound.is_limit else ", default noise levels")
        out.append(row + [f"{fmt(eff)} ({label})" if math.isfinite(eff) else NO_BOUND])
    column = header.index("RMS [m]") if bound.ok else 1
    for kind, label in BOUND_LABELS.items():
        line = [label] + [""] * len(header)
        line[column] = bound.cell(window, kind)
        out.append(line)
    return header + ["RMS / bound"], out


def bound_record(bound: DriveBound, results: list[JobResult]) -> dict[str, Any]:
    """A drive's bound in results.json: :meth:`DriveBound.record` over the whole drive and its windows, and
    each estimator's matching bound and efficiency per window."""
    windows = bound.windows()
    return bound.record(windows) | {
        "efficiency": {r.job.estimator: {w: result_efficiency(r, bound, w) for w in windows} for r in results},
        "bound_kind": {r.job.estimator: bound_kind(r.job.estimator) for r in results},
    }


#: What the bound rows and the efficiency column are, below each drive's tables.
BOUND_TEXT = ("Bound rows: the posterior Cramer-Rao bound on the position error (graphpos.bound: graph-batch's "
              "factor graph with the drive's sensor noise levels, linearised at the truth), the RMS over the window "
              "of sqrt(trace) of the east/north covariance bound. Smoother: from the whole drive; filtering: from the "
              "data up to each epoch. RMS / bound: each estimator's RMS over its matching bound's (the smoother "
              "bound for graph-batch and graph-fixed-lag-smoothed, the filtering bound for the causal estimators); "
              "1 is the best the data allow. A drive that does not carry its sensors' noise levels (not simulated: "
              "recorded, imported) gets graph-batch's default noise levels instead: its bound is a reference, not a "
              "limit, and an estimator may beat it (below 1; the cells say \"default noise levels\").")


def add_drive_sections(report: Report, drive: Drive, results: list[JobResult], sub: Path,
                       layout: str | None = None, bags: bool = True, bound: DriveBound | None = None) -> Section:
    """Tables, plots and exports of one drive (files in the folder ``sub``; ``bags``: see
    :func:`graphpos.io.exports.write_exports`; ``bound``: the drive's position bound, a row and an
    efficiency column in each table and a plot)."""
    sec = report.section(f"Drive {drive.name}")
    sec.text(f"Duration {drive.duration_s:.1f} s; channels {', '.join(drive.channels)}; "
             f"{len(drive.tags)} tags, {len(drive.rsus)} RSUs" + (f"; layout {layout}" if layout else "") + ".")
    broken = [c for c in drive_checks(drive) if c["verdict"] != "ok"]
    if broken:
        sec.text("Drive checks (graphpos info): " + "; ".join(f"{c['level']} {c['name']}: {c['message']}" for c in broken) + ".")
    # windows of identical bounds (in_tunnel and zone:tunnel) score the same epochs: one table for them
    groups = [[WHOLE]] + sorted(same_windows(drive.windows), key=lambda g: g[0])
    for labels in groups:
        window = labels[0]
        header, rows = window_table(results, window)
        if rows and bound is not None:
            header, rows = with_bound(header, rows, results, window, bound)
        if rows:
            names = list(dict.fromkeys(window_name(w) for w in labels))
            sec.table(header, rows, caption=f"Window: {' = '.join(names)} ({', '.join(labels)})")
            line = wheel_line(results, window)
            if line:
                sec.text(line)
    # an estimator that never started (no start pose found) has no track to plot or export
    estimates = [r.estimate for r in results if r.ok and r.estimate is not None and len(r.estimate)]
    if estimates:
        sec.figure(plots.trajectories(drive, estimates, sub / "trajectories.png", layout=layout))
        sec.figure(plots.error_vs_time(drive, estimates, sub / "error_vs_time.png"))
        sec.figure(plots.error_cdf(drive, estimates, sub / "error_cdf.png"))
        speed = plots.speed_error(drive, estimates, sub / "speed_error.png")
        if speed:
            sec.figure(speed)
        if bound is not None and bound.ok:
            sec.figure(plots.bound_vs_time(drive, estimates, bound.bound, sub / "bound_vs_time.png"))
    else:
        sec.text("No estimator gave a track on this drive (see the table and Failures): no plots.")
    if bound is not None:
        sec.text(BOUND_TEXT if bound.ok else f"Position bound: {NO_BOUND} ({bound.reason}).")
    write_exports(sub, drive, [r.estimate for r in results if r.ok and r.estimate is not None], bags=bags)
    sec.text(f"Exports in {sub.name}/: <estimator>.tum (evo), .kml (Google Earth), .geojson, .csv and the same of "
             "the truth (truth.tum ...); all_estimates.kml holds every track"
             + ("; estimates.mcap (Foxglove) and estimates_ros2/ (a ROS 2 bag of nav_msgs/Odometry) hold the drive "
                "and every estimate." if bags else "."))
    return sec


def evaluate(drives: list[tuple[Any, Drive]], estimators: list[str], folder: Path, layout: str | None = None,
             range_model: Any = None, workers: int | None = None, scheduler: str | None = None,
             progress: bool = True, mcap: bool = True, settings: dict[str, dict[str, str]] | None = None,
             initial_pose: Any = None, profile: Any = None, bound: bool = True) -> Outcome:
    """Run ``estimators`` on ``drives`` (without their truth) and write the evaluation folder.

    Parameters
    ----------
    drives : list of (source, Drive)
        The job source for the workers (a :class:`FileSource`, or the drive
        itself) and the drive as loaded here (for plots and exports).
    estimators : list of str
    folder : Path
    layout, range_model, workers, scheduler : see :class:`eval.execution.Job` and :func:`eval.execution.execute`.
    mcap : bool
        Write the MCAP file and the ROS 2 bag of each drive
        (:func:`graphpos.io.exports.write_exports`).
    settings : dict, optional
        ``{estimator name: {key: value text}}`` changes to the estimators'
        default configs (:mod:`graphpos.settings`); stated in the report.
    initial_pose : graphpos.ignition.StartPose, optional
        The user's start pose (``--initial-pose``), given to every estimator
        on every drive; recorded in results.json (``initial_pose``) and the
        report. Each run's ``start`` in results.json says where it started.
    profile : graphpos.profile.SensorProfile, optional
        A sensor profile (``--profile``) for every estimator; recorded in
        results.json (``profile``).
    bound : bool
        Compute each drive's position bound (:mod:`eval.bounds`, in the
        workers) for the tables, a plot and results.json.
    """
    settings = settings or {}
    for source, drive in drives:
        if isinstance(source, FileSource):
            with naming_file(source.path):
                require_truth(drive)
        else:
            require_truth(drive)
    folder = Path(folder)
    with output_folder(folder, "results.json") as out:
        jobs = [
            Job(source, name, layout=layout, range_model=range_model, settings=settings.get(name, {}),
                initial_pose=initial_pose, profile=profile, keep_estimate=True, tag={"drive_index": i})
            for i, (source, _) in enumerate(drives)
            for name in estimators
        ]
        results = execute(jobs, workers=workers, scheduler=scheduler, progress=progress, desc="evaluate")
        bounds = (drive_bounds([(source, layout) for source, _ in drives], workers=workers, scheduler=scheduler,
                               progress=progress)
                  if bound else [None] * len(drives))
        report = Report("graphpos evaluation")
        report.section("Set-up").text(
            f"Estimators: {', '.join(estimators)}. Errors are absolute (estimate minus truth interpolated at the "
            "estimate epochs, no alignment). 2DRMS = 2 x RMS of the horizontal error. ANEES band: two-sided 95 % "
            "chi-square band for independent epochs. RTF = wall time / drive duration."
            + "".join(f" {name} settings: " + ", ".join(f"{k}={v}" for k, v in changed.items()) + "."
                      for name, changed in settings.items())
            + (f" Start pose given: east {initial_pose.east_m:g} m, north {initial_pose.north_m:g} m, yaw "
               f"{math.degrees(initial_pose.yaw_rad):g} deg (1-sigma {initial_pose.position_sigma_m:g} m, "
               f"{math.degrees(initial_pose.yaw_sigma_rad):g} deg)." if initial_pose is not None else "")
            + " Estimators see each drive without its truth; the truth only scores them."
        )
        used: set[str] = set()
        for i, (_, drive) in enumerate(drives):
            mine = [r for r in results if r.job.tag["drive_index"] == i]
            stem = base = safe_name(drive.name)
            copy = 1
            while stem in used:  # two drives of the same name
                copy += 1
                stem = f"{base}-{copy}"
            used.add(stem)
            add_drive_sections(report, drive, mine, out / stem, layout=layout, bags=mcap, bound=bounds[i])
        add_failure_section(report, results)
        warned = [(r, line) for r in results for line in run_warnings(r)]
        if warned:
            report.section("Warnings").table(["drive", "estimator", "warning"],
                                             [[str(r.drive_name), r.job.estimator, line] for r, line in warned])
        write_json(out / "results.json", {
            "command": "evaluate",
            "provenance": provenance(),
            "estimators": estimators,
            "settings": settings,
            "layout": layout,
            "initial_pose": start_pose_record(initial_pose),
            "profile": profile.to_dict() if profile is not None else None,
            "drives": [describe_source(s) | {"name": d.name, "params": d.params,
                                             "checks": [c for c in drive_checks(d) if c["verdict"] != "ok"],
                                             "bound": bound_record(b, [r for r in results if r.job.tag["drive_index"] == i])
                                             if b is not None else None}
                       for i, ((s, d), b) in enumerate(zip(drives, bounds))],
            "results": [result_record(r) for r in results],
        })
        report.write(out)
    return Outcome(results, folder)


def add_failure_section(report: Report, results: list[JobResult]) -> None:
    """List every failed run (nothing when all ran)."""
    failed = failures(results)
    if failed:
        sec = report.section("Failures")
        sec.table(["drive", "estimator", "error"],
                  [[str(r.drive_name or describe_source(r.job.source)), r.job.estimator, r.error or ""] for r in failed])


def file_sources(paths: list[str]) -> list[tuple[FileSource, Drive]]:
    """Read each drive file here (to check it and plot it) and name it as the workers' source."""
    drives = [read_drive(p) for p in paths]  # first: a bad path is the reader's one-line error
    resolved = [Path(p).resolve() for p in paths]
    twice = next((p for p, r in zip(paths, resolved) if resolved.count(r) > 1), None)
    if twice is not None:  # it would be scored twice, as two drives
        raise ConfigError(f"drive {twice} is given more than once")
    return [(FileSource(str(r)), drive) for r, drive in zip(resolved, drives)]
