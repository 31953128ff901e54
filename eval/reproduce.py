"""``graphpos reproduce``: the papers' tables rebuilt on simulated drives, ours beside theirs.

Every (drive, estimator, layout) run is done once, even when several tables
use it, and all runs go to the executor together. Each table cell is the mean
± STD over seeds of the figure the paper reports. A run that fails shows
``FAILED: <reason>`` in its cell, is listed in a Failures section and in
``results.json``; one where the estimator refuses the drive for a missing
channel shows ``n/a``.

Simulator sensor profiles (``--profile ideal|paper|both``, default both;
:data:`PROFILE_CHOICES`): every experiment runs on the drives of each
profile, and each table row gives the published figure beside ours on each
profile, with whether the paper profile's RMS is within ±30 % of the
published one (:data:`MATCH_TOLERANCE`). Each row names the sensors its estimator reads
(:func:`eval.names.sensors_of`); windows carry their display names
(:mod:`eval.names`).

Beside the tables: a summary (how many published RMS figures each profile
matches, which published orderings hold, and the papers' most accurate
filter against each factor graph), the speed error of song2016 Fig. 16, and
the late-measurement and fault studies (:data:`DEGRADED`) on the straight
test (on the last profile run). ``--quick`` runs fewer seeds (2 on the
paper profile, 1 on the others, which run only the papers' rows and
:data:`QUICK_CONTRAST_GRAPHS`; :data:`QUICK_SINGLE_SEED` and
:data:`QUICK_CONTRAST_SKIP`), the Table 4 patterns :data:`QUICK_TABLE4`, the
studies :data:`QUICK_DEGRADED` on one seed, the first :data:`QUICK_PLAZA_S`
of Plaza and :data:`QUICK_MRCLAM_S` of the robots :data:`QUICK_MRCLAM_ROBOTS`;
the report says so. ``only`` / ``--only`` picks experiments.

Position bound (issue 18): every simulated table has a row per posterior
Cramer-Rao bound (smoother, filtering; :mod:`eval.bounds`) on the same
drives, and per profile each row's efficiency (its RMS over its matching
bound's RMS); ``results.json`` holds them (``tables[key].bound`` and each
row's ``efficiency``). A drive the bound cannot be computed on shows "—"
and why.

Real data: when the Plaza file is present, the estimators that can use its
sensors (UWB ranges, wheel odometry, gyro; no accelerometers, no compass) run
on it. The ranging is not calibrated on the evaluated drive's truth: Plaza1
is the only Plaza drive available, so the range model is a self-calibration
on the drive without its truth (:func:`graphpos.graph.calibration.calibrate_range_scale`:
the radio's common range scale and a robust sigma from graph-batch's
solution). When the MRCLAM Dataset 6 folder is present, robots 1-5 run the
odometry and factor-graph estimators (:data:`MRCLAM_ESTIMATORS`). Missing
data is a note in its section, not an error.

Truth is for scoring only (issue 13): every run hands its estimator the
drive without its truth (:func:`eval.execution.run_job`) and scores the
output against the full drive afterwards.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from eval import plots
from eval.bounds import BOUND_LABELS, NO_BOUND, DriveBound, bound_kind, bound_label, bounds_cell, drive_bounds
from eval.evaluate import Outcome, add_failure_section, cell_error, result_record
from eval.execution import Job, JobResult, SimSource, execute, load_drive, provenance
from eval.experiments import (GRAPH_ESTIMATORS, LIU2016_BOUND_M, ORDERING_ONLY_TABLES, RANGES_ONLY_GRAPH, SONG2016_TABLE4,
                              Experiment, Row, experiments)
from eval.metrics import WHOLE
from eval.names import sensors_of, window_name
from eval.report import Report, fmt, mean_spread, write_json
from graphpos.drive import Drive, Window
from graphpos.io.mrclam import MRCLAM_SOURCE
from graphpos.io.outputs import output_folder, safe_name
from graphpos.sim.params import PROFILES

#: Seeds per experiment.
SEEDS_FULL = 5
SEEDS_QUICK = 2
#: --quick: seeds of the profiles other than the paper profile (the ideal profile is the contrast, not
#: the comparison with the papers).
SEEDS_QUICK_CONTRAST = 1
#: song2016 Table 4 patterns run by --quick (one constant-angular-velocity curve, one lane change).
QUICK_TABLE4 = ("constant", "lane-change-curve")
#: --quick runs the profiles other than the paper profile on every experiment but these (key prefixes):
#: their cells on those profiles say "not run (--quick)".
QUICK_CONTRAST_SKIP = ("song2016-table4/", "liu2016-zones")
#: --quick runs these (key prefixes) on one seed of the paper profile too (their drives are the longest).
QUICK_SINGLE_SEED = ("song2016-table4/", "liu2016-zones")
#: --quick runs the profiles other than the paper profile on the papers' rows and these graph rows only.
QUICK_CONTRAST_GRAPHS = ("graph-batch",)
#: What a cell says for a profile --quick did not run.
NOT_RUN = "not run (--quick)"
#: The degraded-data variants --quick runs (of :data:`DEGRADED`).
QUICK_DEGRADED = ("nominal", "RFID 0.5–2 s late", "RFID blackout 20 s")
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

#: ``--profile`` choices: the simulator sensor profiles (:data:`graphpos.sim.params.PROFILES`) the
#: experiments run on. ``paper`` is the profile meant to match the papers' road tests; ``ideal`` the
#: simulator's white-noise sensors.
PROFILE_CHOICES = {"ideal": ("ideal",), "paper": ("paper",), "both": ("ideal", "paper")}
#: The profile compared with the published figures (the ±30 % column and the summary's count).
PAPER_PROFILE = "paper"
#: The paper profile's compass terms (its deviation, named where the report explains the causal graphs' figures).
_PAPER_COMPASS = PROFILES[PAPER_PROFILE]["compass"]
#: What each profile is, for the report.
PROFILE_TEXT = {
    "ideal": "white-noise sensors: Gauss-Markov IMU biases, a 1 % wheel scale error, an RSS-only RFID radio",
    "paper": "sensor errors set to what the papers' road tests show (graphpos.sim.params.PROFILES['paper'])",
}
#: A published RMS "matches" when ours is within this fraction of it.
MATCH_TOLERANCE = 0.30
#: A reversed ordering is "within the seeds' spread" when its paired mean difference is under this many standard errors.
ORDERING_NOISE_SE = 2.0

_RunKey = tuple  # (SimSource or "plaza" or "mrclam/<robot>", estimator, layout, held: see Row.held)


def default_plaza_path() -> Path:
    """``<repo>/../shared/data/plaza/Plaza1.mat``."""
    return Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "plaza" / "Plaza1.mat"


def default_mrclam_path() -> Path:
    """``<repo>/../shared/data/mrclam/MRCLAM_Dataset6``."""
    return Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam" / "MRCLAM_Dataset6"


#: --quick scores the first this many seconds of Plaza (the whole 32-minute drive otherwise).
QUICK_PLAZA_S = 120.0
#: MRCLAM robots run (--quick: its robots and the first seconds of each; the whole 15-minute recording
#: otherwise).
MRCLAM_ROBOTS = (1, 2, 3, 4, 5)
QUICK_MRCLAM_ROBOTS = (3,)
QUICK_MRCLAM_S = 90.0

#: Estimators tried on Plaza (those lacking a sensor Plaza does not have report n/a). Dead reckoning
#: is not among them, here or on MRCLAM: it reads no ranges, so on a recorded drive its only start
#: would be one the user gives (``--initial-pose``), and the harness may not take one from the truth.
PLAZA_ESTIMATORS = ("multilateration", "rfid-ekf", "fusion-ekf", "fukf", "two-level-ekf", RANGES_ONLY_GRAPH,
                    *GRAPH_ESTIMATORS)
#: Estimators tried on MRCLAM: the factor graphs (odometry and landmark ranges).
MRCLAM_ESTIMATORS = (RANGES_ONLY_GRAPH, *GRAPH_ESTIMATORS)


class _Runs:
    """Deduplicated jobs: one per (source, estimator, layout)."""

    def __init__(self) -> None:
        self.jobs: dict[_RunKey, Job] = {}

    def add(self, source: Any, estimator: str, layout: str | None, keep: bool = False,
            range_model: Any = None, name: str = "plaza", held: bool = False) -> _RunKey:
        key = (source if isinstance(source, SimSource) else name, estimator, layout, held)
        old = self.jobs.get(key)
        if old is None or (keep and not old.keep_estimate):
            self.jobs[key] = Job(source, estimator, layout=layout, keep_estimate=keep, range_model=range_model, hold_last_output=held)
        return key


def first_seconds(drive: Drive, seconds: float) -> Drive:
    """The first ``seconds`` of a drive (every channel cut at the same time; windows clipped)."""
    end = drive.start_s + seconds
    windows = [Window(w.label, w.start_s, min(w.end_s, end)) for w in drive.windows if w.start_s <= end]
    return drive.replace(name=f"{drive.name}-first{seconds:.0f}s",
                         channels={k: ch.between(drive.start_s, end) for k, ch in drive.channels.items()},
                         windows=tuple(windows), params={**drive.params, "cut_after_s": seconds})


def sim_profile(profile: str) -> str:
    """The simulator profile run for a ``--profile`` name; a ConfigError for an unknown one."""
    from graphpos.sim.params import PROFILES

    if profile in PROFILES:
        return profile
    from graphpos.errors import ConfigError

    raise ConfigError(f"unknown simulator sensor profile {profile!r} (known: {', '.join(PROFILES)})")


def with_profile(overrides_json: str, profile: str) -> str:
    """Simulation overrides (JSON) with the top-level ``profile`` set."""
    over = json.loads(overrides_json) if overrides_json else {}
    return json.dumps({**over, "profile": profile}, sort_keys=True)


def _results(res: dict, sources: list[SimSource], row: Row) -> list[JobResult]:
    """A row's results on some drives (none for the runs --quick leaves out)."""
    return [res[key] for s in sources if (key := _row_key(s, row)) in res]


def _row_key(source: SimSource, row: Row) -> _RunKey:
    """The run of a table's row on a drive."""
    return source, row.estimator, row.layout, row.held


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
        return cell_error(results[0]) if results else NOT_RUN
    text = mean_spread([window_stat(r, window, stat) for r in good])
    failed = len(results) - len(good)
    return text + (f" ({failed} of {len(results)} runs failed)" if failed else "")


def max_rms_cell(results: list[JobResult], window: str) -> str:
    """``max / RMS`` (each mean ± STD over seeds), or why there is no figure."""
    good = [r for r in results if r.ok]
    if not good:
        return cell_error(results[0], width=60) if results else NOT_RUN
    text = (mean_spread([window_stat(r, window, "max_m") for r in good]) + " / "
            + mean_spread([window_stat(r, window, "rms_m") for r in good]))
    failed = len(results) - len(good)
    return text + (f" ({failed} of {len(results)} runs failed)" if failed else "")


def mean_stat(results: list[JobResult], window: str, stat: str) -> float:
    vals = [window_stat(r, window, stat) for r in results]
    vals = [v for v in vals if np.isfinite(v)]
    return float(np.mean(vals)) if vals else math.nan


def match_cell(ours: float, published: float | None) -> str:
    """Whether ours is within :data:`MATCH_TOLERANCE` of the published figure, and by how much it differs."""
    if published is None or not np.isfinite(ours) or not published:
        return "–"
    off = ours / published - 1.0
    return f"{'yes' if abs(off) <= MATCH_TOLERANCE else 'no'} ({off:+.0%})".replace("-", "−")


def _profile_header(profile: str, runs_as: str) -> str:
    return f"ours, {profile} profile" + (f" (run as {runs_as})" if runs_as != profile else "")


def _experiment_table(exp: Experiment, res: dict[_RunKey, JobResult], sources: dict[str, list[SimSource]],
                      profiles: dict[str, str], channels: list[str]) -> tuple[list[str], list[list[str]], list[dict]]:
    """Header, rows and the JSON record of one max/RMS table: per row the published figure and ours on
    each profile."""
    match_on = PAPER_PROFILE if PAPER_PROFILE in profiles else None
    header = ["estimator", "sensors", "layout", "published max / RMS [m]"]
    header += [f"{_profile_header(p, s)}: max / RMS [m]" for p, s in profiles.items()]
    if match_on:
        header.append(f"{match_on}-profile RMS within ±{MATCH_TOLERANCE:.0%} of published?")
    header += ["rate [Hz]", "wall [s] (mean)"]
    rows, records = [], []
    for row in exp.all_rows():
        by_profile = {p: _results(res, sources[p], row) for p in profiles}
        pub = row.published
        line = [row.label, sensors_of(row.estimator, channels), row.layout or "–",
                f"{fmt(pub[0])} / {fmt(pub[1])}" if pub else "–"]
        line += [max_rms_cell(rs, exp.window) for rs in by_profile.values()]
        if match_on:
            line.append(match_cell(mean_stat(by_profile[match_on], exp.window, "rms_m"), pub[1] if pub else None))
        last = list(by_profile.values())[-1]
        rate, _velocity = _run_info(last)
        walls = [r.metrics["wall_time_s"] for r in last if r.ok]
        line += [rate, fmt(np.mean(walls)) if walls else "–"]
        rows.append(line)
        per_profile = {p: {"sim_profile": profiles[p],
                           "seeds": [s.seed for s in sources[p]],
                           "max_m": [window_stat(r, exp.window, "max_m") for r in rs],
                           "rms_m": [window_stat(r, exp.window, "rms_m") for r in rs],
                           "rms_in_tunnel_m": [window_stat(r, "in_tunnel", "rms_m") for r in rs],
                           "errors": [r.error for r in rs]}
                       for p, rs in by_profile.items()}
        primary = per_profile[list(profiles)[-1]]
        records.append({
            "estimator": row.estimator, "label": row.label, "layout": row.layout, "published_max_rms_m": row.published,
            "sensors": sensors_of(row.estimator, channels),
            "max_m": primary["max_m"], "rms_m": primary["rms_m"], "errors": primary["errors"],
            "profiles": per_profile,
        })
    return header, rows, records


def _run_info(results: list[JobResult]) -> tuple[str, str]:
    good = [r for r in results if r.ok]
    if not good:
        return "–", "–"
    return fmt(np.median([r.metrics["output_rate_hz"] for r in good]), 1), fmt(good[0].metrics["velocity_provided"])


def _zones_table(exp: Experiment, res: dict[_RunKey, JobResult], sources: dict[str, list[SimSource]],
                 profiles: dict[str, str], channels: list[str]) -> tuple[list[str], list[list[str]], list[dict]]:
    """liu2016: 2DRMS per zone window, per profile."""
    zones = _zones(exp, res, sources, profiles)

    def bound(zone: str) -> str:
        b = LIU2016_BOUND_M.get(zone[len("zone:"):])
        return f"published ≤ {b:.1f}" if b else "published: no figure"

    header = ["estimator", "sensors"]
    header += [f"{window_name(z)} ({bound(z)}), {p}" for z in zones for p in profiles]
    header += [f"{window_name(WHOLE)}, {p}" for p in profiles]
    rows, records = [], []
    for row in exp.all_rows():
        by_profile = {p: _results(res, sources[p], row) for p in profiles}
        rows.append([row.label, sensors_of(row.estimator, channels)]
                    + [seeds_cell(by_profile[p], z, "drms2_m") for z in zones for p in profiles]
                    + [seeds_cell(by_profile[p], WHOLE, "drms2_m") for p in profiles])
        per_profile = {p: {"drms2_m": {z: [window_stat(r, z, "drms2_m") for r in rs] for z in zones + [WHOLE]},
                           "errors": [r.error for r in rs], "sim_profile": profiles[p]}
                       for p, rs in by_profile.items()}
        primary = per_profile[list(profiles)[-1]]
        records.append({"estimator": row.estimator, "sensors": sensors_of(row.estimator, channels),
                        "drms2_m": primary["drms2_m"], "errors": primary["errors"], "profiles": per_profile})
    return header, rows, records


def _zones(exp: Experiment, res: dict[_RunKey, JobResult], sources: dict[str, list[SimSource]],
           profiles: dict[str, str]) -> list[str]:
    """The ``zone:*`` windows the runs of a table were scored in, in first-seen order."""
    zones: list[str] = []
    for row in exp.all_rows():
        for p in profiles:
            for s in sources[p]:
                r = res.get(_row_key(s, row))
                if r is not None and r.ok:
                    zones += [w for w in r.metrics["windows"] if w.startswith("zone:") and w not in zones]
    return zones


def _bound_keys(exp: Experiment, sources: dict[str, list[SimSource]]) -> list[tuple[SimSource, str | None]]:
    """The (drive, layout) bounds a table needs: each drive through its graph rows' layout and every row's."""
    layouts = dict.fromkeys([exp.graph_layout] + [r.layout for r in exp.all_rows()])
    return [(s, lay) for srcs in sources.values() for s in srcs for lay in layouts]


def _efficiency_cell(values: list[float], kind: str, run: bool) -> str:
    """Mean ± STD over seeds of the efficiency (RMS / bound) and the bound it is against."""
    if not run:
        return NOT_RUN
    text = mean_spread(values)
    return NO_BOUND if text == "–" else f"{text} ({kind})"


def _add_bound(exp: Experiment, header: list[str], rows: list[list[str]], records: list[dict],
               res: dict[_RunKey, JobResult], sources: dict[str, list[SimSource]], profiles: dict[str, str],
               bounds: dict[tuple[SimSource, str | None], DriveBound], channels: list[str]) -> dict[str, Any]:
    """The position bound in a table (:func:`_experiment_table` or :func:`_zones_table`), in place.

    Per profile an efficiency column: each row's RMS in the table's window over its matching bound's RMS
    (:func:`eval.bounds.bound_kind`; the bound of the row's own layout, the same seed), mean ± STD over
    seeds, also in the row's record (``efficiency``). One row per bound kind through the graph rows'
    layout, in the figures' columns: ``– / RMS`` in a max / RMS table, 2DRMS (2 x RMS) per zone in a
    zones table. Returns the bounds' JSON record: per profile, per drive and layout, the bound's RMS in
    the table's window, in the tunnel and in the zones, with its timing or why there is none.
    """
    header += [f"RMS / bound, {p}" for p in profiles]
    for row, line, record in zip(exp.all_rows(), rows, records):
        eff = {p: [bounds[(s, row.layout)].efficiency(row.estimator, window_stat(res[key], exp.window, "rms_m"), exp.window)
                   for s in sources[p] if (key := _row_key(s, row)) in res] for p in profiles}
        kind = bound_kind(row.estimator)
        line += [_efficiency_cell(eff[p], bound_label(row.estimator), bool(_results(res, sources[p], row))) for p in profiles]
        record["efficiency"] = {p: {"bound_kind": kind, "window": exp.window, "values": v} for p, v in eff.items()}
    zones = _zones(exp, res, sources, profiles) if exp.metric == "drms2_zones" else []
    sensors = sensors_of(GRAPH_ESTIMATORS[0], channels)
    bs = {p: [bounds[(s, exp.graph_layout)] for s in sources[p]] for p in profiles}
    for kind, label in BOUND_LABELS.items():
        if exp.metric == "drms2_zones":
            cells = ([bounds_cell(bs[p], z, kind, scale=2.0, empty=NOT_RUN) for z in zones for p in profiles]
                     + [bounds_cell(bs[p], WHOLE, kind, scale=2.0, empty=NOT_RUN) for p in profiles])
            line = [label, sensors, *cells]
        else:
            line = [label, sensors, exp.graph_layout or "–", "–",
                    *[bounds_cell(bs[p], exp.window, kind, prefix="– / ", empty=NOT_RUN) for p in profiles]]
        rows.append(line + [""] * (len(header) - len(line)))
    windows = list(dict.fromkeys([exp.window, "in_tunnel", *zones]))
    return {p: [bounds[key].record(windows) | {"seed": key[0].seed}
                for key in _bound_keys(exp, {p: sources[p]})] for p in profiles}


#: Column titles of the figures graphpos.ranging.table1 returns (distance errors in m, RSS errors in 0-255 units).
_TABLE1_COLUMNS = {"mean": "ours mean [m]", "std": "ours STD [m]", "rms": "ours RMS [m]",
                   "rss_mean": "ours mean [RSS]", "rss_std": "ours STD [RSS]"}


def _table1(seeds: int) -> tuple[list[str], list[list[str]], dict]:
    """song2016 Table 1 from :mod:`graphpos.ranging.table1`, over calibration seeds."""
    from graphpos.ranging.drive_models import CALIBRATION_SEED
    from graphpos.ranging.table1 import PUBLISHED_TABLE1, table1

    runs = [table1(CALIBRATION_SEED + k) for k in range(seeds)]
    keys = list(next(iter(next(iter(runs[0].values())).values())))
    header = ["environment", "model", "published mean", "published STD"] + [_TABLE1_COLUMNS.get(k, f"ours {k}") for k in keys]
    rows = []
    for env, models in runs[0].items():
        for kind in models:
            pub = PUBLISHED_TABLE1.get(env, {}).get(kind, (math.nan, math.nan))
            rows.append([env, kind, fmt(pub[0]), fmt(pub[1])] + [mean_spread([r[env][kind][k] for r in runs]) for k in keys])
    return header, rows, {"seeds": [CALIBRATION_SEED + k for k in range(seeds)], "figures": runs}


def _table1_child(seeds: int, conn) -> None:
    try:
        conn.send(("ok", _table1(seeds)))
    except BaseException as exc:  # noqa: BLE001 - said in the parent, which computes it again
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


class _Table1Process:
    """:func:`_table1` in a forked process started before the executor's workers (no thread of this
    process runs while they fork); :meth:`result` waits for it, and computes it here if the process died."""

    def __init__(self, seeds: int) -> None:
        import multiprocessing

        self.seeds = seeds
        self.proc = None
        try:
            ctx = multiprocessing.get_context("fork")
            self.conn, child = ctx.Pipe(duplex=False)
            self.proc = ctx.Process(target=_table1_child, args=(seeds, child), daemon=True)
            self.proc.start()
            child.close()
        except (ValueError, OSError):  # no fork on this platform: computed in result()
            self.proc = None

    def result(self) -> tuple[list[str], list[list[str]], dict]:
        if self.proc is not None:
            try:
                status, value = self.conn.recv()
            except (EOFError, OSError):
                status, value = "error", "process died"
            finally:
                self.proc.join()
            if status == "ok":
                return value
        return _table1(self.seeds)


HOW_TO_READ = (
    "Simulated drives are not the papers' road tests. Every figure below comes from drives simulated to each "
    "paper's specification (route, speeds, sensor rates and noise where the paper gives them; the rest is "
    "ours); the published figures come from one real drive each, with a vehicle, tunnel and radio we only know "
    "from the paper. Treat ours beside theirs as two different experiments: whether the orderings agree says "
    "more than whether the metres do.",
    "Errors are Euclidean 2-D position errors in metres against the simulated truth, absolute (no alignment). "
    "Each 'ours' cell is max / RMS, each the mean ± STD over the seeds; 'published' is the paper's single test. "
    "FAILED cells name the error (the full message is in Failures and results.json); n/a means the estimator "
    "lacks a sensor the drive does not carry.",
    "Sensors: the 'sensors' column says what each row reads. The papers' RFID-only rows (song2016 Table 2, "
    "song2014 Table 2) use RFID ranges alone; graph-ranges is the factor graph on the same RFID ranges alone, "
    "while the other graph rows also use the IMU, the wheel speed, the compass and the GNSS fixes of the "
    "approach road, so they do not compete on equal terms there.",
    "Factor graphs (graph-*: ours, the papers have no such figures). Causal estimates, each epoch from the "
    "data up to that epoch, as a filter gives them: graph-isam2 and graph-fixed-lag (the fixed-lag smoother's "
    "live output). They are the same smoother but for one thing: graph-isam2 by default learns the sensor "
    "profile online (range scale and noise levels, re-solving the track so far), which a fixed-lag smoother, "
    "keeping no history, cannot; with learning off (--set graph-isam2.learn_online=false) the two agree to 1e-9 m. Smoothed "
    "estimates, which also use later data: graph-batch (the whole drive at once: the best the data allow, "
    "available only after the drive) and graph-fixed-lag-smoothed (each epoch once the smoother's lag has "
    "passed: a few seconds late, online). The papers' filters are all causal.",
)
#: How to read the bound rows and efficiency columns (with ``bound``).
BOUND_HOW_TO_READ = (
    "Bound rows: the posterior Cramer-Rao bound on the position error on the same drives (graphpos.bound: "
    "graph-batch's factor graph with the simulator's sensor noise levels, linearised at the truth, through the "
    "graph rows' layout), the RMS of sqrt(trace) of its east/north covariance over the table's window, mean ± STD "
    "over seeds (2DRMS: twice that). Smoother: from the whole drive, what graph-batch at best achieves; filtering: "
    "from the data up to each epoch, what a causal estimator at best achieves. 'RMS / bound': each row's RMS over "
    "its matching bound's RMS on the same drive (smoother for graph-batch, graph-fixed-lag-smoothed and graph-ranges, filtering "
    "for the causal estimators; the bound of the row's own layout), mean ± STD over seeds: 1 is the best the data "
    "allow. The bound assumes white Gaussian sensor errors; the paper profile's are not, so there the bound is that "
    "of a simpler problem. Rows on RFID ranges only are held to the same bound, of more sensors than they read "
    "(marked so): a bound of ranges alone would be higher and their efficiency nearer 1."
)


def _select(exps: list[Experiment], only: list[str] | None) -> list[Experiment]:
    """The experiments whose key is, or starts with, one of ``only`` (all when None)."""
    if not only:
        return exps
    from graphpos.errors import ConfigError

    chosen = [e for e in exps if any(e.key.startswith(k) for k in only)]
    if not chosen:
        raise ConfigError(f"--only {', '.join(only)}: no such experiment (known: {', '.join(e.key for e in exps)})")
    return chosen


def reproduce(folder: Path, quick: bool = False, seeds: int | None = None, plaza: Path | None = None,
              workers: int | None = None, scheduler: str | None = None, progress: bool = True,
              profile: str = "both", only: list[str] | None = None, duration_s: float | None = None,
              mrclam: Path | None = None, degraded: bool = True, table1: bool = True,
              real_data: bool = True, bound: bool = True) -> Outcome:
    """Run every experiment and write the reproduction folder (see the module docstring).

    ``profile``: a key of :data:`PROFILE_CHOICES` (the simulator sensor profiles to run); ``only``:
    experiment keys (or key prefixes, ``song2016-table4``) to run; ``duration_s``: simulate only the
    first seconds of each drive (tests); ``degraded``, ``table1``, ``real_data``: run the late-data and
    fault studies, song2016 Table 1 and the Plaza and MRCLAM sections; ``bound``: the position bound's rows
    and efficiency columns (:func:`_add_bound`).
    """
    from graphpos.errors import ConfigError

    started = time.perf_counter()
    folder = Path(folder)
    if profile not in PROFILE_CHOICES:
        raise ConfigError(f"--profile {profile!r}: choose one of {', '.join(PROFILE_CHOICES)}")
    profiles = {p: sim_profile(p) for p in PROFILE_CHOICES[profile]}
    primary = list(profiles)[-1]  # plots, degraded studies and the summary's graph columns
    n_seeds = seeds if seeds is not None else (SEEDS_QUICK if quick else SEEDS_FULL)
    if n_seeds < 1:
        raise ConfigError(f"--seeds must be at least 1, got {n_seeds}")
    seeds_of = {p: (min(n_seeds, SEEDS_QUICK_CONTRAST) if quick and p != PAPER_PROFILE and len(profiles) > 1 else n_seeds)
                for p in profiles}
    exps = [e for e in _select(experiments(), only)
            if not (quick and e.key.startswith("song2016-table4/") and e.pattern not in QUICK_TABLE4)]

    def seeds_on(p: str, exp: Experiment) -> int:
        if not quick:
            return seeds_of[p]
        if p != PAPER_PROFILE and len(profiles) > 1 and exp.key.startswith(QUICK_CONTRAST_SKIP):
            return 0
        return min(seeds_of[p], 1) if exp.key.startswith(QUICK_SINGLE_SEED) else seeds_of[p]
    plaza_path = plaza if plaza is not None else default_plaza_path()
    mrclam_path = mrclam if mrclam is not None else default_mrclam_path()

    runs = _Runs()
    sources: dict[str, dict[str, list[SimSource]]] = {}
    for exp in exps:
        sources[exp.key] = {
            p: [SimSource(exp.scenario, exp.pattern, seed, duration_s=duration_s,
                          overrides_json=with_profile(exp.overrides_json, sim))
                for seed in range(seeds_on(p, exp))]
            for p, sim in profiles.items()}
        for p, srcs in sources[exp.key].items():
            for seed, src in enumerate(srcs):
                for row in exp.all_rows():
                    if quick and p != PAPER_PROFILE and len(profiles) > 1 and not (
                            row in exp.rows or row.estimator in QUICK_CONTRAST_GRAPHS):
                        continue  # --quick: the other profiles are the papers' rows' contrast
                    runs.add(src, row.estimator, row.layout, keep=seed == 0 and p == primary, held=row.held)
    degraded_seeds = 1 if quick else n_seeds
    degraded_srcs = {label: [SimSource("paper-straight", None, seed, duration_s=duration_s,
                                       overrides_json=with_profile("", profiles[primary]),
                                       rfid_latency_s=late, faults_json=faults)
                             for seed in range(degraded_seeds)] for label, (late, faults) in DEGRADED.items()
                     if not quick or label in QUICK_DEGRADED} if degraded else {}
    for srcs in degraded_srcs.values():
        for src in srcs:
            for name, layout in DEGRADED_ESTIMATORS:
                runs.add(src, name, layout)
    plaza_drive = None
    if real_data and (plaza is not None or plaza_path.is_file()):  # a given file must import (clear errors)
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
    if real_data and mrclam is not None and not Path(mrclam).is_dir():
        raise ConfigError(f"--mrclam {mrclam}: no such folder ({MRCLAM_SOURCE})")
    mrclam_drives: dict[int, Drive] = {}
    mrclam_skip = ""
    if real_data and (mrclam is not None or mrclam_path.is_dir()):
        from graphpos.io.mrclam import import_mrclam

        robots = QUICK_MRCLAM_ROBOTS if quick else MRCLAM_ROBOTS
        for robot in robots:
            try:
                drive = import_mrclam(mrclam_path, robot)
            except Exception as exc:  # a robot's files missing or broken: said in the section
                mrclam_skip += f" Robot {robot} not imported: {type(exc).__name__}: {exc}."
                continue
            mrclam_drives[robot] = first_seconds(drive, QUICK_MRCLAM_S) if quick else drive
            for name in MRCLAM_ESTIMATORS:
                runs.add(mrclam_drives[robot], name, None, keep=robot == robots[0], name=f"mrclam/{robot}")
        if mrclam is not None and not mrclam_drives:  # the folder the user named is not a dataset: refused, as a missing one
            raise ConfigError(f"--mrclam {mrclam}: no robot could be imported ({mrclam_skip.strip()})")

    with output_folder(folder, "results.json") as out:
        # song2016 Table 1 fits its range models in a process of its own while the workers run the drives
        table1_job = _Table1Process(1 if quick else n_seeds) if table1 else None
        keys = list(runs.jobs)
        results = execute([runs.jobs[k] for k in keys], workers=workers, scheduler=scheduler, progress=progress,
                          desc="reproduce")
        res = dict(zip(keys, results))
        bound_keys = list(dict.fromkeys(k for exp in exps for k in _bound_keys(exp, sources[exp.key]))) if bound else []
        bounds = dict(zip(bound_keys, drive_bounds(bound_keys, workers=workers, scheduler=scheduler, progress=progress)))
        if progress:  # the plots take a while after the last bar
            print("reproduce: drawing the plots and writing the report", file=sys.stderr, flush=True)

        title = "graphpos reproduce — the papers' tables on simulated drives" + (" (quick)" if quick else "")
        report = Report(title)
        how = report.section("How to read this")
        for paragraph in HOW_TO_READ:
            how.text(paragraph)
        if bound:
            how.text(BOUND_HOW_TO_READ)
        how.text("Simulator sensor profiles (graphpos simulate --profile): "
                 + "; ".join(f"{p}: {PROFILE_TEXT.get(sim, sim)}, {seeds_of[p]} seed(s)"
                             for p, sim in profiles.items())
                 + f". The '{PAPER_PROFILE}' column of each table is the one to compare with the published figures; "
                   f"'within ±{MATCH_TOLERANCE:.0%}' compares its RMS with the published RMS."
                 + (" Plots show one drive: seed 0 of the " + primary + " profile (the tables average every seed)."))
        if quick:
            longest = " and ".join(k.rstrip("/") for k in QUICK_SINGLE_SEED)
            others = [p for p in profiles if p != PAPER_PROFILE]
            how.text("What --quick cuts (the full run has none of these cuts: "
                     f"{SEEDS_FULL if seeds is None else n_seeds} seeds of every table on every profile): "
                     + "; ".join(
                         [f"the {p} profile runs {seeds_of[p]} seed(s) ({min(seeds_of[p], 1)} on {longest})"
                          for p in profiles if p == PAPER_PROFILE or len(profiles) == 1]
                         + [f"the {p} profile runs {seeds_of[p]} seed(s), not {longest}, and of the graph rows "
                            f"only {', '.join(QUICK_CONTRAST_GRAPHS)}" for p in others if len(profiles) > 1])
                     + f"; song2016 Table 4 patterns {', '.join(QUICK_TABLE4)} only (of {len(SONG2016_TABLE4)}); "
                       f"one calibration seed of song2016 Table 1; "
                       f"one seed of {len(QUICK_DEGRADED)} of the {len(DEGRADED)} late-data and fault studies; the "
                       f"first {QUICK_PLAZA_S:.0f} s of Plaza; MRCLAM robots "
                       f"{', '.join(map(str, QUICK_MRCLAM_ROBOTS))} only, the first {QUICK_MRCLAM_S:.0f} s of each.")
        summary = report.section("Summary: our orderings and figures against the papers'")
        tables: dict[str, Any] = {}

        if table1_job is not None:
            header, rows, record = table1_job.result()
            report.section("song2016 Table 1 — RSS to distance fitting errors").table(header, rows).text(
                "From graphpos.ranging.table1: held-out readings of simulated calibration collections, mean ± STD over "
                "calibration seeds. The paper does not define its 'fitting error' or its unit; ours is given both as a "
                "distance error [m] and as an RSS error [0-255 units] (see that module's docstring)."
            )
            tables["song2016-table1"] = record

        plotted: set = set()
        for exp in exps:
            srcs = sources[exp.key]
            first = srcs[primary][0]
            channels = list(load_drive(first).channels)
            sec = report.section(exp.title)
            sec.text(f"Scenario {exp.scenario}" + (f", pattern {exp.pattern}" if exp.pattern else "")
                     + f"; window: {window_name(exp.window)}; seeds per profile: "
                     + ", ".join(f"{p} {len(v) or NOT_RUN}" for p, v in srcs.items()) + "."
                     + (f" {exp.note}" if exp.note else ""))
            make = _zones_table if exp.metric == "drms2_zones" else _experiment_table
            header, rows, record = make(exp, res, srcs, profiles, channels)
            bound_record = _add_bound(exp, header, rows, record, res, srcs, profiles, bounds, channels) if bound else None
            sec.table(header, rows)
            tables[exp.key] = {"title": exp.title, "scenario": exp.scenario, "pattern": exp.pattern,
                               "window": exp.window, "seeds": [s.seed for s in srcs[primary]],
                               "profiles": {p: {"sim_profile": sim, "seeds": [s.seed for s in srcs[p]]}
                                            for p, sim in profiles.items()},
                               "rows": record, "bound": bound_record}
            plot_key = (first, tuple((r.estimator, r.layout) for r in exp.all_rows()))
            if plot_key not in plotted:  # song2014 Tables 4 and 5/6 show the same runs in two windows
                plotted.add(plot_key)
                estimates = [res[_row_key(first, r)].estimate for r in exp.all_rows()
                             if res[_row_key(first, r)].ok and len(res[_row_key(first, r)].estimate)]
                if estimates:
                    drive = load_drive(first)
                    sub = out / safe_name(exp.key)
                    caption = (f"One drive: seed {first.seed} of {len(srcs[primary])}, {primary} profile "
                               f"({drive.name}); the table averages every seed.")
                    sec.figure(plots.trajectories(drive, estimates, sub / "trajectories.png"), caption)
                    sec.figure(plots.error_vs_time(drive, estimates, sub / "error_vs_time.png"), caption)
                    if exp.key == "song2016-table3":
                        speed = plots.speed_error(drive, estimates, sub / "speed_error.png")
                        if speed:
                            sec.figure(speed, caption)

        summary_record = _fill_summary(summary, [e for e in exps if e.metric == "max_rms"], res, sources, profiles)
        tables["summary"] = summary_record
        _speed_section(report, res, sources.get("song2016-table3", {}).get(primary, []), tables)
        if degraded_srcs:
            _degraded_section(report, res, degraded_srcs, tables, primary)
        real = report.section("Real data")
        real.text("Recorded drives with their own ground truth: no simulator, no profile. The papers have no "
                  "figures for these; they show how the estimators fare on sensors we did not model.")
        if not real_data:
            real.text("Not run (real_data=False).")
        else:
            if plaza_drive is not None:
                _plaza_section(report, res, plaza_drive, out, tables)
            else:
                report.section("Plaza", level=3).text(f"Skipped: {plaza_path} not found (give --plaza FILE.mat).")
            if mrclam_drives:
                _mrclam_section(report, res, mrclam_drives, out, tables, mrclam_skip)
            else:
                missing = "no robot could be imported" if mrclam_path.is_dir() else "not found"
                report.section("MRCLAM", level=3).text(
                    f"Skipped: {mrclam_path} {missing} (give --mrclam DIR; {MRCLAM_SOURCE}).{mrclam_skip}")

        add_failure_section(report, results)
        took = time.perf_counter() - started
        busy = sum(r.metrics["wall_time_s"] for r in results if r.ok)
        report.section("Run").text(f"{len(results)} runs ({len(results) - sum(r.ok for r in results)} without figures) "
                                   f"in {took:.0f} s of wall time ({busy:.0f} s inside the estimators, summed over "
                                   f"workers); profiles {', '.join(profiles)}; seeds "
                                   + ", ".join(f"{p} {n}" for p, n in seeds_of.items()) + f"; quick={quick}.")
        write_json(out / "results.json", {
            "command": "reproduce", "quick": quick, "seeds": n_seeds, "wall_time_s": took,
            "profiles": {p: {"sim_profile": sim, "seeds": seeds_of[p]} for p, sim in profiles.items()},
            "match_tolerance": MATCH_TOLERANCE,
            "provenance": provenance(), "tables": tables, "runs": [result_record(r) for r in results],
        })
        report.write(out)
    return Outcome(results, folder)


def _ordering(exp: Experiment, rms: dict[Row, float], per_seed: dict[Row, list[float]] | None = None) -> tuple[list[str], str]:
    """The published order of the paper's rows (lowest RMS first) and whether ours keeps it.

    Where it does not, each published pair ours reverses is named with its
    paired difference over the seeds (``per_seed``: each row's RMS on the
    same drives, in the same order): mean +- standard error, and whether the
    reversal is within the seeds' spread (under :data:`ORDERING_NOISE_SE`
    standard errors), which more seeds may settle either way, or beyond it.
    """
    rows = [r for r in exp.rows if r.published]
    published = [r.label for r in sorted(rows, key=lambda r: r.published[1])]
    if any(not np.isfinite(rms[r]) for r in rows):
        return published, "–"
    ours = [r.label for r in sorted(rows, key=lambda r: rms[r])]
    if ours == published:
        return published, "yes"
    notes = []
    for better in rows:
        for worse in rows:
            if better.published[1] < worse.published[1] and rms[better] > rms[worse]:
                notes.append(_reversal(better, worse, rms, per_seed))
    return published, "no: " + " < ".join(ours) + "".join(f"; {n}" for n in notes)


def paired_difference(a: list[float], b: list[float]) -> tuple[float, float, int]:
    """Mean and standard error of ``a - b`` over the seeds both have a finite figure for, and how many (SE NaN under 2)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return math.nan, math.nan, 0
    se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size >= 2 else math.nan
    return float(d.mean()), se, int(d.size)


def reversal_verdict(mean: float, se: float) -> str:
    """Whether a paired difference is within the seeds' spread (:data:`ORDERING_NOISE_SE`) or beyond it."""
    return "within the seeds' spread" if abs(mean) < ORDERING_NOISE_SE * se else "beyond the seeds' spread"


def _reversal(better: Row, worse: Row, rms: dict[Row, float], per_seed: dict[Row, list[float]] | None) -> str:
    """``better`` (published) behind ``worse`` on ours: by how much, paired over the seeds, and whether beyond their spread."""
    text = f"{better.label} behind {worse.label} by {rms[better] - rms[worse]:.2f} m"
    if per_seed is None:
        return text
    mean, se, n = paired_difference(per_seed[better], per_seed[worse])
    if n < 2:
        return text + " (one seed: no spread to judge)"
    return f"{better.label} behind {worse.label} by {mean:.2f} ± {se:.2f} m (paired over {n} seeds: {reversal_verdict(mean, se)})"


def _fill_summary(sec, exps: list[Experiment], res: dict, sources: dict[str, dict[str, list[SimSource]]],
                  profiles: dict[str, str]) -> dict:
    """Per table: published orderings kept, published RMS matched, and the best paper estimator against the graphs."""
    primary = list(profiles)[-1]
    order_rows, best_rows, record = [], [], {"orderings": [], "matches": {}}
    matched = {p: [0, 0] for p in profiles}
    targets = {p: [0, 0] for p in profiles}  # the same, without the ORDERING_ONLY_TABLES
    for exp in exps:
        rms = {p: {r: mean_stat(_results(res, sources[exp.key][p], r), exp.window, "rms_m")
                   for r in exp.all_rows()} for p in profiles}
        per_seed = {p: {r: [window_stat(res[k], exp.window, "rms_m") if (k := _row_key(s, r)) in res else math.nan
                            for s in sources[exp.key][p]] for r in exp.rows} for p in profiles}
        line = [exp.title, window_name(exp.window)]
        published = []
        holds = {}
        for p in profiles:
            published, holds[p] = _ordering(exp, rms[p], per_seed[p])
            if not sources[exp.key][p]:
                holds[p] = NOT_RUN
        line.append(" < ".join(published))
        line += [holds[p] for p in profiles]
        for p in profiles:
            if not sources[exp.key][p]:
                line.append(NOT_RUN)
                continue
            pubs = [(rms[p][r], r.published[1]) for r in exp.rows if r.published]
            good = sum(np.isfinite(o) and abs(o / pub - 1.0) <= MATCH_TOLERANCE for o, pub in pubs)
            matched[p][0] += good
            matched[p][1] += len(pubs)
            if exp.key not in ORDERING_ONLY_TABLES:
                targets[p][0] += good
                targets[p][1] += len(pubs)
            line.append(f"{good} of {len(pubs)}")
        order_rows.append(line)
        record["orderings"].append({"table": exp.key, "published_order": published, "holds": holds})

        ranked = sorted((v, r.label) for r, v in rms[primary].items() if r in exp.rows and np.isfinite(v))
        best = f"{ranked[0][1]}: {ranked[0][0]:.2f}" if ranked else "–"
        extra = {r.estimator: r for r in exp.all_rows()[len(exp.rows):]}
        best_rows.append([exp.title, window_name(exp.window), best]
                         + [fmt(rms[primary][extra[g]]) if g in extra else "–" for g in (RANGES_ONLY_GRAPH, *GRAPH_ESTIMATORS)])
    record["matches"] = {p: {"within": m[0], "of": m[1], "targets_within": targets[p][0], "targets_of": targets[p][1]}
                         for p, m in matched.items()}
    sec.text("How many published RMS figures ours match within "
             f"±{MATCH_TOLERANCE:.0%} (mean over seeds, each table's window): "
             + "; ".join(f"{p} profile {m[0]} of {m[1]}" for p, m in matched.items())
             + ". Without the RFID-only Tables 2, whose magnitudes the paper profile does not aim at (their "
               "order only; benchmarks/paper_profile.py measures these against the 80 % target): "
             + "; ".join(f"{p} profile {t[0]} of {t[1]}" for p, t in targets.items())
             + ". An ordering holds when our RMS ranks the paper's estimators of a table as the paper does. Where "
               "it does not, the cell names each pair reversed with its difference paired over the same seeds "
               f"(mean ± standard error) and whether that is within the seeds' spread (under {ORDERING_NOISE_SE:g} "
               "standard errors: a tie that more seeds may settle either way) or beyond it.")
    sec.table(["table", "window", "published order (lowest RMS first)", *[f"order holds, {p}" for p in profiles],
               *[f"RMS within ±{MATCH_TOLERANCE:.0%}, {p}" for p in profiles]], order_rows,
              caption="Orderings and matches per table")
    sec.text(f"RMS error in metres ({primary} profile, mean over seeds) in each table's window: the most accurate "
             "of the paper's estimators on our drives, and each factor-graph estimator on the same drives "
             f"({RANGES_ONLY_GRAPH} runs on the RFID-only tables alone)."
             + (" On the paper profile the causal graphs (graph-isam2, graph-fixed-lag) may trail the best paper "
                "filter. The main cause is the profile's compass, which deviates by a constant "
                f"{_PAPER_COMPASS['bias_min_deg']:g}-{_PAPER_COMPASS['bias_max_deg']:g} degrees. "
                "graph-batch solves for that deviation over the whole drive. graph-isam2 applies a deviation it "
                "learnt online only once a second, longer learning finds it again, on these 76 s tests only in "
                "their last part. graph-fixed-lag keeps no history to learn it from. A profile calibrated on an earlier "
                "drive of the same sensors (graphpos calibrate, then --profile) gives them the deviation from the "
                "start (README, 'Starting an estimator and calibrating a sensor set')." if primary == PAPER_PROFILE else ""))
    sec.table(["table", "window", "best paper estimator (ours)", RANGES_ONLY_GRAPH, *GRAPH_ESTIMATORS], best_rows,
              caption="The papers' best filter against the factor graphs")
    return record


def _speed_section(report: Report, res: dict, srcs: list[SimSource], tables: dict) -> None:
    """song2016 Fig. 16: speed error of the estimators with velocity, beside the raw wheel speed."""
    if not srcs:
        return
    by_name: dict[str, list[JobResult]] = defaultdict(list)
    by_drive: dict[SimSource, JobResult] = {}  # the raw wheel speed is the drive's: one figure per seed
    for (src, name, _layout, held), r in res.items():
        if src in srcs and not held and r.ok and r.metrics["velocity_provided"]:
            by_name[name].append(r)
            by_drive.setdefault(src, r)
    if not by_name:
        return
    wheel = [r.metrics["windows"][WHOLE]["wheel_speed"] for r in by_drive.values()]
    rows = [["raw wheel speed", mean_spread([w["mean_mps"] for w in wheel if w], 3),
             mean_spread([w["rms_mps"] for w in wheel if w], 3)]]
    for name, rs in by_name.items():
        sp = [r.metrics["windows"][WHOLE]["speed"] for r in rs]
        rows.append([name, mean_spread([s["mean_mps"] for s in sp], 3), mean_spread([s["rms_mps"] for s in sp], 3)])
    report.section("Speed error against truth (song2016 Fig. 16), straight test").table(
        ["source", "mean [m/s]", "RMS [m/s]"], rows)
    tables["song2016-fig16"] = {"rows": rows}


def _degraded_section(report: Report, res: dict, degraded: dict[str, list[SimSource]], tables: dict,
                      profile: str = "ideal") -> None:
    """Late readings and injected faults against the nominal drives (same seeds), and the error inside each fault."""
    rows, fault_rows, record = [], [], []
    for name, layout in DEGRADED_ESTIMATORS:
        row = [name, layout]
        for label, srcs in degraded.items():
            rs = [res[(s, name, layout, False)] for s in srcs]
            row.append(seeds_cell(rs, "in_tunnel", "rms_m"))
            entry = {"estimator": name, "variant": label, "rms_in_tunnel_m": [window_stat(r, "in_tunnel", "rms_m") for r in rs]}
            for window in sorted({w for r in rs if r.ok for w in r.metrics["windows"] if w.startswith("fault:")}):
                fault_rows.append([label, name, window_name(window), seeds_cell(rs, window, "max_m"), seeds_cell(rs, window, "rms_m"),
                                   seeds_cell(rs, "in_tunnel", "rms_m")])
                entry[f"rms_in_{window}_m"] = [window_stat(r, window, "rms_m") for r in rs]
            record.append(entry)
        rows.append(row)
    sec = report.section(f"Late measurements and faults (paper-straight, {profile} profile, RMS in the tunnel)")
    sec.table(["estimator", "layout", *degraded], rows).text(
        f"Same drives (seeds {', '.join(str(s.seed) for s in next(iter(degraded.values())))}) in every column. Late: RFID readings arrive 0.5–2 s after they were taken; a filter "
        "processing in arrival order sees old readings, a graph attaches them to the keyframe of their own "
        "timestamp. Faults from graphpos.sim.faults, one episode 30 % into the drive (dead tags: the whole drive).")
    if fault_rows:
        sec.table(["fault", "estimator", "window", "max in fault [m]", "RMS in fault [m]", "RMS in tunnel [m]"],
                  sorted(fault_rows, key=lambda r: (r[0], r[1])), caption="Error inside each fault window")
    tables["degraded"] = record


def _plaza_section(report: Report, res: dict, drive, folder: Path, tables: dict) -> None:
    rs = {name: res[("plaza", name, None, False)] for name in PLAZA_ESTIMATORS}
    header = ["estimator", "max [m]", "RMS [m]", "mean [m]", "p95 [m]", "scored / outputs", "rate [Hz]", "wall [s]"]
    rows = []
    for name, r in rs.items():
        if not r.ok:
            rows.append([name, cell_error(r)] + [""] * (len(header) - 2))
            continue
        not_started = (r.metrics.get("diagnostics") or {}).get("not_started")
        if r.metrics["n_outputs"] == 0:
            rows.append([name, f"not started: {not_started}" if not_started else "no output"]
                        + [""] * (len(header) - 2))
            continue
        p = r.metrics["windows"][WHOLE]["position"]
        rows.append([name, fmt(p["max_m"]), fmt(p["rms_m"]), fmt(p["mean_m"]), fmt(p["p95_m"]),
                     f"{p['n']} / {r.metrics['n_outputs']}", fmt(r.metrics["output_rate_hz"], 1),
                     fmt(r.metrics["wall_time_s"])])
    sec = report.section(f"Plaza ({drive.name})", level=3)
    sec.text(f"{drive.duration_s:.0f} s of driving: UWB ranges to beacons, wheel odometry and gyro; ground truth "
             "from the dataset. Every estimator uses one range calibration, self-calibrated from the drive "
             "without its truth (graphpos.graph.calibrate_range_scale: range scale "
             f"{drive.params['range_model']['scale']:.4f}, sigma {drive.params['range_model']['sigma0_m']:.2f} m). "
             "One drive, so no spread."
             + (f" --quick scores only the first {drive.params['cut_after_s']:.0f} s." if "cut_after_s" in drive.params else ""))
    sec.table(header, rows)
    estimates = [r.estimate for r in rs.values() if r.ok and len(r.estimate)]  # not the ones that never started
    if estimates:
        caption = f"Plaza: {drive.name}, the one recorded drive."
        sec.figure(plots.trajectories(drive, estimates, folder / "plaza" / "trajectories.png"), caption)
        sec.figure(plots.error_vs_time(drive, estimates, folder / "plaza" / "error_vs_time.png"), caption)
    tables["plaza"] = {"rows": rows}



def _real_cell(r: JobResult) -> str:
    """RMS of a real-data run, or why there is none."""
    if not r.ok:
        return cell_error(r, width=40)
    not_started = (r.metrics.get("diagnostics") or {}).get("not_started")
    if r.metrics["n_outputs"] == 0:
        return "not started (no start pose found)" if not_started else "no output"
    return fmt(window_stat(r, WHOLE, "rms_m"))


def _mrclam_section(report: Report, res: dict, drives: dict[int, Drive], folder: Path, tables: dict,
                    skipped: str = "") -> None:
    """UTIAS MRCLAM: each robot's odometry and landmark ranges, RMS per robot."""
    robots = list(drives)
    with_mean = len(robots) > 1  # the mean of one robot would repeat its cell
    header = ["estimator", "sensors", *[f"robot {n} RMS [m]" for n in robots], *(["mean RMS [m]"] * with_mean)]
    rows, record = [], []
    for name in MRCLAM_ESTIMATORS:
        rs = [res[(f"mrclam/{n}", name, None, False)] for n in robots]
        cells = [_real_cell(r) for r in rs]
        mean = (fmt(mean_stat(rs, WHOLE, "rms_m")) if all(np.isfinite(window_stat(r, WHOLE, "rms_m")) for r in rs)
                else "–")
        rows.append([name, sensors_of(name, list(drives[robots[0]].channels)), *cells, *([mean] * with_mean)])
        record.append({"estimator": name, "robots": robots, "rms_m": [window_stat(r, WHOLE, "rms_m") for r in rs],
                       "errors": [r.error for r in rs]})
    first = drives[robots[0]]
    cut = first.params.get("cut_after_s")
    sec = report.section("MRCLAM (UTIAS Dataset 6)", level=3)
    sec.text("Five robots in a room: wheel speed and turn rate (commanded, 67-100 Hz), camera ranges to "
             "surveyed landmarks (2-5 Hz, as RFID ranges), Vicon truth (graphpos.io.mrclam). No accelerometers "
             "and no compass: estimators needing them report n/a. Default range model (the camera's ranges are "
             "unbiased within a few centimetres)."
             + (" 'mean RMS' over the robots in the table, only when each of them ran." if with_mean else "")
             + (f" --quick: robot(s) {', '.join(map(str, robots))} only, the first {cut:.0f} s of each." if cut else "")
             + skipped)
    sec.table(header, rows)
    shown = robots[0]
    estimates = [r.estimate for name in MRCLAM_ESTIMATORS
                 for r in [res[(f"mrclam/{shown}", name, None, False)]] if r.ok and r.estimate is not None and len(r.estimate)]
    if estimates:
        caption = f"MRCLAM robot {shown} alone ({drives[shown].name}); the table gives every robot."
        sec.figure(plots.trajectories(drives[shown], estimates, folder / "mrclam" / "trajectories.png"), caption)
        sec.figure(plots.error_vs_time(drives[shown], estimates, folder / "mrclam" / "error_vs_time.png"), caption)
    tables["mrclam"] = {"rows": record}
