"""Commands ``evaluate``, ``reproduce`` and ``layout-study`` (the ``eval`` package).

Each writes a folder with ``results.json``, ``report.md``, ``report.html`` and
plots. The estimators see each drive without its truth; the truth only
scores them (issue 13). A run that fails (an estimator not available, or one
that raises on a drive) is reported in its table cell and in
``results.json``; the command then prints a summary of the failures on
stderr and exits with status 1. User mistakes (bad options, a bad
``--initial-pose``, a drive without truth, an output folder that cannot be
written) exit with status 2. The output folder is checked before any work
and written by :func:`graphpos.io.outputs.output_folder`: complete or
absent, an earlier output of graphpos replaced, a folder holding other files
refused.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from graphpos.cli import OUTPUT_FOLDER_HELP, add_output_option, estimator_names, one_line, warning_line
from graphpos.cli.estimators import add_initial_pose_option, add_settings_options, estimator_settings, initial_pose


def _add_execution_options(p: argparse.ArgumentParser) -> None:
    add_output_option(p, "DIR", OUTPUT_FOLDER_HELP, "--output")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://host:8786, instead of the local pool")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def register(sub) -> None:
    p = sub.add_parser("evaluate",
                       description="Run estimators over drives with truth; write results.json, report.md/html, "
                                   "plots and, per drive, the exports `graphpos run` writes: TUM/KML/GeoJSON/CSV of "
                                   "each estimate and of the truth, estimates.mcap (Foxglove) and estimates_ros2/ "
                                   "(a ROS 2 bag of nav_msgs/Odometry).")
    p.add_argument("drives", nargs="+", help="drive MCAP files (with a truth channel)")
    p.add_argument("-e", "--estimator", dest="estimators", action="append", required=True, metavar="NAME",
                   help="estimator name (repeat, or comma-separate); see `graphpos estimators`")
    p.add_argument("--layout", default=None, help="tag layout the estimators hear (default: every tag)")
    p.add_argument("--range-model", default=None, type=str, metavar="FILE", help="saved range model (JSON)")
    add_settings_options(p)
    add_initial_pose_option(p)
    from graphpos.cli.calibrate import add_profile_option

    add_profile_option(p)
    _add_execution_options(p)
    p.set_defaults(func=_evaluate)

    p = sub.add_parser("reproduce",
                       description="The papers' experiments on simulated drives built to their specifications, "
                                   "published figures beside ours on each simulator sensor profile, the "
                                   "factor-graph estimators as extra rows; Plaza and MRCLAM when present.")
    p.add_argument("--quick", action="store_true",
                   help="fewer seeds, patterns and studies, the first seconds of the real data (under 2 minutes on 2 cores)")
    p.add_argument("--seeds", type=int, default=None,
                   help="seeds per experiment (default 5; quick: 2 on the paper profile, 1 on the ideal one)")
    p.add_argument("--profile", choices=("ideal", "paper", "both"), default="both",
                   help="simulator sensor profile of the simulated drives (graphpos simulate --profile): ideal "
                        "(white-noise sensors), paper (sensor errors like the papers' road tests) or both "
                        "(default); not a calibration profile")
    p.add_argument("--only", action="append", default=None, metavar="KEY",
                   help="run only this experiment (repeat; an experiment's key, e.g. song2016-table3, or a prefix, "
                        "e.g. song2016-table4; a wrong key lists them; song2016 Table 1, the range model's fit, is not "
                        "one: it always runs)")
    p.add_argument("--plaza", type=Path, default=None, metavar="FILE.mat",
                   help="the Plaza dataset (default: <repo>/../shared/data/plaza/Plaza1.mat when present)")
    p.add_argument("--mrclam", type=Path, default=None, metavar="DIR",
                   help="a UTIAS MRCLAM dataset folder (default: <repo>/../shared/data/mrclam/MRCLAM_Dataset6 "
                        "when present)")
    _add_execution_options(p)
    p.set_defaults(func=_reproduce)

    p = sub.add_parser("layout-study",
                       description="RMS in the tunnel against the number of tags (dense, optimized, groups every "
                                   "60/90/120 m) for fusion-ekf, fukf, graph-isam2 and graph-batch over seeds.")
    p.add_argument("scenario", help="simulation scenario (e.g. paper-straight)")
    p.add_argument("--seeds", type=int, default=3, help="seeds per layout (default 3)")
    p.add_argument("-e", "--estimator", dest="estimators", action="append", default=None, metavar="NAME",
                   help="estimators (default: fusion-ekf, fukf, graph-isam2, graph-batch)")
    _add_execution_options(p)
    p.set_defaults(func=_layout_study)


def _finish(outcome, started: float, command: str) -> int:
    failed = outcome.failures
    took = time.perf_counter() - started
    print(f"{command}: wrote {one_line(str(outcome.folder))}/report.md, report.html, results.json in {took:.1f} s")
    if failed:
        print(f"{command}: {len(failed)} of {len(outcome.results)} runs failed:", file=sys.stderr)
        for r in failed:
            where = r.drive_name or "?"
            print(one_line(f"  {r.job.estimator} on {where}: {r.error}"), file=sys.stderr)
        return 1
    return 0


def _evaluate(args) -> int:
    from eval.evaluate import evaluate, file_sources, run_warnings
    from graphpos.io.checks import drive_checks, require_usable
    from graphpos.io.outputs import check_output_folder
    from graphpos.ranging import load_range_model

    started = time.perf_counter()
    check_output_folder(args.output)
    names = estimator_names(args.estimators)
    settings = estimator_settings(args, names)
    from graphpos.cli.calibrate import profile as profile_of

    pose = initial_pose(args)
    if args.range_model is not None:
        load_range_model(args.range_model)  # a bad file is its one-line error here, not in every worker
    drives = file_sources(args.drives)
    # a nonsense drive is refused here, before any work; warnings are said last, so that a refusal stays one line
    drive_warnings = [line for path, (_, drive) in zip(args.drives, drives) for line in require_usable(drive_checks(drive), path)]
    outcome = evaluate(drives, names, args.output, layout=args.layout, range_model=args.range_model,
                       workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress, settings=settings,
                       initial_pose=pose, profile=profile_of(args))
    status = _finish(outcome, started, "evaluate")
    for r in outcome.results:  # what an estimator said of a drive (also in the report's Warnings)
        for line in run_warnings(r):
            print(warning_line("evaluate", f"{r.job.estimator} on {r.drive_name}: {line}"), file=sys.stderr)
    for line in drive_warnings:
        print(warning_line("evaluate", line), file=sys.stderr)
    return status


def _reproduce(args) -> int:
    from eval.reproduce import reproduce
    from graphpos.io.outputs import check_output_folder

    started = time.perf_counter()
    check_output_folder(args.output)
    outcome = reproduce(args.output, quick=args.quick, seeds=args.seeds, plaza=args.plaza, mrclam=args.mrclam,
                        profile=args.profile, only=args.only,
                        workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress)
    return _finish(outcome, started, "reproduce")


def _layout_study(args) -> int:
    from eval.layout_study import layout_study
    from graphpos.io.outputs import check_output_folder

    started = time.perf_counter()
    check_output_folder(args.output)
    outcome = layout_study(args.scenario, args.output, seeds=args.seeds,
                           estimators=estimator_names(args.estimators) if args.estimators else None,
                           workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress)
    return _finish(outcome, started, "layout-study")
