"""``graphpos layout-study``: how few tags suffice (song2016 §5.1: 42 against 16 tags).

Every named tag layout of the scenario's drives (dense, optimized, groups
every 60/90/120 m) is heard by each estimator on the same drives (seeds); the
RMS error in the tunnel against the number of tags is the cost/accuracy
curve. The drives are the same for every layout: a layout only drops the
readings of the tags it does not keep (:meth:`graphpos.drive.Drive.with_layout`).
Beside the errors, the position bound of each layout (:mod:`eval.bounds`:
the RMS over the tunnel of the filtering and smoother bounds, mean over the
same seeds) says how much of the error the tags leave whatever the estimator.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from eval import plots
from eval.bounds import KINDS, bounds_cell, drive_bounds
from eval.evaluate import Outcome, add_failure_section, result_record
from eval.execution import Job, SimSource, execute, load_drive, provenance
from eval.reproduce import seeds_cell, window_stat
from eval.report import Report, write_json
from graphpos.errors import ConfigError
from graphpos.io.outputs import output_folder

DEFAULT_ESTIMATORS = ("fusion-ekf", "fukf", "graph-isam2", "graph-batch")
#: Reference without tags.
BASELINE = "dr"
#: Layouts in order of decreasing tag count, where the drive has them.
LAYOUTS = ("dense", "optimized", "groups-60m", "groups-90m", "groups-120m")


def layout_study(scenario: str, folder: Path, seeds: int = 3, estimators: list[str] | None = None,
                 workers: int | None = None, scheduler: str | None = None, progress: bool = True,
                 duration_s: float | None = None) -> Outcome:
    """Run the study and write ``results.json``, ``report.md``/``.html`` and ``cost_accuracy.png``."""
    from graphpos.registry import require_known
    from graphpos.sim import SCENARIOS

    started = time.perf_counter()
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{scenario}' (known: {', '.join(SCENARIOS)})")
    if seeds < 1:
        raise ConfigError(f"--seeds must be at least 1, got {seeds}")
    names = list(estimators or DEFAULT_ESTIMATORS)
    require_known(names)  # refused before any work, as evaluate does, not once per job
    sources = [SimSource(scenario, None, seed, duration_s=duration_s) for seed in range(seeds)]
    drive = load_drive(sources[0])
    layouts = [name for name in LAYOUTS if name in drive.tags.layouts]
    layouts += sorted(set(drive.tags.layouts) - set(layouts))
    if len(drive.tags) == 0:
        raise ConfigError(f"scenario '{scenario}' has no RFID tags: nothing to study")
    n_tags = {name: int(drive.tags.layout(name).size) for name in layouts}
    folder = Path(folder)
    with output_folder(folder, "results.json") as out:
        jobs = [Job(src, est, layout=lay, tag={"layout": lay}) for lay in layouts for est in names for src in sources]
        jobs += [Job(src, BASELINE) for src in sources]
        results = execute(jobs, workers=workers, scheduler=scheduler, progress=progress, desc="layout-study")
        by = {(j.layout, j.estimator, j.source): r for j, r in zip(jobs, results)}
        bound_keys = [(src, lay) for lay in layouts for src in sources]
        bounds = dict(zip(bound_keys, drive_bounds(bound_keys, workers=workers, scheduler=scheduler,
                                                    progress=progress)))

        points: dict[str, list[tuple[float, float, float]]] = {}
        bound_points: dict[str, list[tuple[float, float]]] = {kind: [] for kind in KINDS}
        rows, record = [], []
        for lay in layouts:
            row = [lay, str(n_tags[lay])]
            bs = [bounds[(s, lay)] for s in sources]
            bound_m = {kind: [b.rms_m("in_tunnel", kind) for b in bs] for kind in KINDS}
            bound_mean_m = {kind: float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
                            for kind, v in bound_m.items()}
            for kind in KINDS:
                bound_points[kind].append((n_tags[lay], bound_mean_m[kind]))
            bound_fields = {f"bound_{kind}_m": bound_mean_m[kind] for kind in KINDS} | {
                "bound_seeds_m": bound_m, "bound_errors": [b.reason for b in bs]}
            for est in names:
                rs = [by[(lay, est, s)] for s in sources]
                rms = [window_stat(r, "in_tunnel", "rms_m") for r in rs]
                ok = [v for v in rms if np.isfinite(v)]
                if ok:
                    points.setdefault(est, []).append((n_tags[lay], float(np.mean(ok)), float(np.std(ok))))
                row.append(seeds_cell(rs, "in_tunnel", "rms_m"))
                record.append({"layout": lay, "n_tags": n_tags[lay], "estimator": est, "rms_in_tunnel_m": rms,
                               "max_in_tunnel_m": [window_stat(r, "in_tunnel", "max_m") for r in rs],
                               "errors": [r.error for r in rs]} | bound_fields)
            rows.append(row + [bounds_cell(bs, "in_tunnel", kind) for kind in KINDS])
        baseline = [by[(None, BASELINE, s)] for s in sources]
        rows.append([f"no tags ({BASELINE})", "0"] + [seeds_cell(baseline, "in_tunnel", "rms_m")] * len(names)
                    + ["–"] * len(KINDS))
        base_rms = [window_stat(r, "in_tunnel", "rms_m") for r in baseline]
        record.append({"layout": None, "n_tags": 0, "estimator": BASELINE, "rms_in_tunnel_m": base_rms,
                       "errors": [r.error for r in baseline]})

        report = Report(f"graphpos layout-study — {scenario}")
        sec = report.section("RMS position error in the tunnel against the number of tags")
        sec.text(f"Mean ± STD over {seeds} seed(s) of the Euclidean RMS error in the in_tunnel window, metres. "
                 "Same drives for every layout; a layout keeps only its tags' readings. Bound columns: the RMS over "
                 "the tunnel of sqrt(trace) of the posterior Cramer-Rao bound (graphpos.bound) on the same drives, "
                 "mean ± STD over the seeds; filtering for the causal estimators, smoother for graph-batch.")
        sec.table(["layout", "tags"] + names + [f"bound ({kind}) [m]" for kind in KINDS], rows)
        sec.text(f"The last row is dead reckoning ({BASELINE}: wheel speed, gyro and compass, no tags) on the same "
                 "drives: what the tags have to beat.")
        ok = [v for v in base_rms if np.isfinite(v)]
        sec.figure(plots.cost_accuracy(points, out / "cost_accuracy.png", f"{scenario}: cost against accuracy",
                                       baseline_m=float(np.mean(ok)) if ok else None, bounds=bound_points))
        add_failure_section(report, results)
        took = time.perf_counter() - started
        report.section("Run").text(f"{len(results)} runs in {took:.0f} s.")
        write_json(out / "results.json", {
            "command": "layout-study", "scenario": scenario, "seeds": seeds, "estimators": names,
            "n_tags": n_tags, "wall_time_s": took, "provenance": provenance(), "curve": record,
            "runs": [result_record(r) for r in results],
        })
        report.write(out)
    return Outcome(results, folder)
