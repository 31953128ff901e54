"""Commands ``estimators`` (list them) and ``run`` (estimators over one drive).

``graphpos run DRIVE.mcap -e NAME [-e NAME ...] [--layout L] [--range-model F] [--initial-pose E,N,YAW_DEG] -o DIR``
(``--out-dir`` is the old spelling of ``-o``) writes into DIR, for any drive,
with truth or without, the exports of :func:`graphpos.io.exports.write_exports`
(the same as ``evaluate`` writes for each drive):

- ``NAME.csv`` per estimator that finished (:data:`graphpos.estimate.CSV_COLUMNS`,
  empty cells where the estimator does not estimate a quantity; only the
  header when it never started: no start pose given and none found in the
  drive), and ``NAME.tum`` (evo), ``NAME.kml`` (Google Earth),
  ``NAME.geojson`` when it gave an output;
- ``truth.csv``, ``.tum``, ``.kml``, ``.geojson``: the drive's truth at its
  own rate (when the drive has truth: ``evo_ape tum truth.tum NAME.tum``);
- ``all_estimates.kml``: every track in one Google Earth file;
- ``estimates.mcap``: the drive with every estimate, for Foxglove;
- ``estimates_ros2/``: a ROS 2 bag, each estimate (and the truth) as
  ``nav_msgs/Odometry`` on ``/graphpos/NAME/odometry`` (:mod:`graphpos.io.ros2_bag`);
- ``run.json``: the start pose given, ``failed`` (the estimators that
  raised), ``not_applicable`` (those the drive lacks channels for) and per
  estimator its ``status`` (``ok``, ``failed`` or ``not_applicable``), settings
  and config, and when it finished its wall time, ``real_time_factor``
  (wall time over the drive's duration, as in ``results.json``), output
  rate, where it started (``start``, or ``not_started``) and diagnostics, when it failed
  its ``error`` (and the ``traceback`` of an internal error).

The estimators see the drive without its truth (truth is for scoring only,
issue 13: :meth:`graphpos.drive.Drive.without_truth`). An estimator
lacking a channel it needs is not run: a warning line names it and the
channel, ``run.json`` gives it the status ``not_applicable`` and lists it
under ``not_applicable``, and the others run (as ``evaluate`` marks such a
run n/a); when none can run, each is one error line, status 2 and nothing
written. One estimator's failure while it runs does not
cost the others their results: each failure is one line on
stderr naming the estimator and the reason, the others' files are written,
and the status is 1. When every estimator fails nothing is written (status
2, or 1 when an internal error was among the failures).

The output folder is checked before the drive is read and written by
:func:`graphpos.io.outputs.output_folder`: complete or absent, an earlier
output of graphpos replaced, a folder holding other files refused.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import traceback
from pathlib import Path
from typing import TYPE_CHECKING

from graphpos.cli import OUTPUT_FOLDER_HELP, add_output_option, error_line, estimator_names, one_line, progress_line, warning_line
from graphpos.errors import ConfigError, GraphposError, MissingChannelError, naming_file
from graphpos.estimate import Estimate

if TYPE_CHECKING:
    from graphpos.ignition import StartPose


def register(sub) -> None:
    p = sub.add_parser("estimators",
                       description="Every estimator `graphpos run` knows: name, what it is, the channels it "
                                   "needs (`rsu or gnss`: one of them) and, in brackets, the others it uses when "
                                   "present.")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list of {name, summary, needs, required_channels, required_any (groups of "
                        "which one channel is needed), optional_channels, config}")
    p.set_defaults(func=_estimators)

    p = sub.add_parser("run",
                       description="Run one or more estimators over a drive and write into a folder their estimates "
                                   "(NAME.csv, .tum, .kml, .geojson), the truth's (truth.*, when the drive has it), "
                                   "all_estimates.kml, estimates.mcap (Foxglove), estimates_ros2/ (a ROS 2 bag of "
                                   "nav_msgs/Odometry) and run.json.")
    p.add_argument("drive", type=Path, metavar="DRIVE.mcap", help="drive file (see `graphpos simulate`)")
    p.add_argument("-e", "--estimator", dest="estimators", action="append", required=True, metavar="NAME",
                   help="estimator name (repeat, or comma-separate; see `graphpos estimators`)")
    p.add_argument("--layout", metavar="L", help="use only the tags of this named layout (e.g. optimized)")
    p.add_argument("--range-model", type=Path, metavar="F",
                   help="range model JSON (from `graphpos ranging fit`); default: the drive's default model")
    add_output_option(p, "DIR", OUTPUT_FOLDER_HELP, "--out-dir")
    add_settings_options(p)
    add_initial_pose_option(p)
    from graphpos.cli.calibrate import add_profile_option

    add_profile_option(p)
    p.set_defaults(func=_run)


def add_initial_pose_option(p: argparse.ArgumentParser) -> None:
    """``--initial-pose``, read back by :func:`initial_pose`."""
    p.add_argument("--initial-pose", default=None, metavar="E,N,YAW_DEG[,SIGMA_M[,SIGMA_YAW_DEG]]",
                   help="start every estimator at this pose: east and north in metres (the drive's local frame), "
                        "yaw from east, counter-clockwise, in degrees, optional 1-sigmas in metres and degrees "
                        "(default 1 m, 5 deg); write --initial-pose=-5,2,90 when E is negative; default: the "
                        "drive's stored start pose, else found from the sensors")


def initial_pose(args: argparse.Namespace) -> "StartPose | None":
    """The :class:`~graphpos.ignition.StartPose` of ``--initial-pose``, or None.

    Raises
    ------
    ConfigError
        A value that is not ``E,N,YAW_DEG[,SIGMA_M[,SIGMA_YAW_DEG]]`` with
        finite, plausible numbers and positive sigmas.
    """
    from graphpos.ignition import StartPose

    text = getattr(args, "initial_pose", None)
    return None if text is None else StartPose.parse(text)


def add_settings_options(p: argparse.ArgumentParser) -> None:
    """``--set`` and ``--final``, read back by :func:`estimator_settings`."""
    p.add_argument("--set", dest="settings", action="append", default=[], metavar="[NAME.]KEY=VALUE",
                   help="change an estimator setting (repeat); without NAME, every selected estimator that "
                        "has KEY; `graphpos estimators --json` lists the settings (e.g. --set fixed_lag_s=20, "
                        "--set graph-isam2.max_delay_s=5)")
    p.add_argument("--final", action="store_true",
                   help="graph-isam2 returns its final smoothed trajectory instead of the causal one "
                        "(same as --set graph-isam2.final=true)")


def estimator_settings(args: argparse.Namespace, names: list[str]) -> dict[str, dict[str, str]]:
    """``{estimator name: {key: value text}}`` from ``--set`` and ``--final``."""
    from graphpos.registry import require_known
    from graphpos.settings import parse_settings

    items = list(args.settings)
    if args.final:
        if "graph-isam2" not in names:
            raise ConfigError("--final applies to graph-isam2, which is not selected")
        items.append("graph-isam2.final=true")
    classes = require_known(names)
    return parse_settings(items, names, {n: cls.default_config() for n, cls in classes.items()})


def _estimators(args: argparse.Namespace) -> int:
    from graphpos.registry import estimator_classes
    from graphpos.settings import config_dict

    rows = []
    for name, cls in estimator_classes().items():
        cfg = cls.default_config()
        named = {*cls.required_channels, *(c for group in cls.required_any for c in group)}
        rows.append({
            "name": name,
            "summary": cls.summary,
            "needs": cls.needs(),
            "required_channels": list(cls.required_channels),
            "required_any": [list(group) for group in cls.required_any],
            "optional_channels": [c for c in cls.optional_channels if c not in named],
            "config": config_dict(cfg) if dataclasses.is_dataclass(cfg) else {},
        })
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        opt = f" (+ {', '.join(r['optional_channels'])})" if r["optional_channels"] else ""
        print(f"{r['name']:<18} needs {r['needs']}{opt}")
        print(f"{'':<18} {r['summary']}")
    return 0


def _run(args: argparse.Namespace) -> int:
    from graphpos.io import read_drive
    from graphpos.io.checks import drive_checks, require_usable
    from graphpos.io.outputs import check_output_folder, output_folder, safe_name
    from graphpos.ranging import load_range_model
    from graphpos.registry import make_estimator

    names = list(dict.fromkeys(estimator_names(args.estimators)))
    if not names:
        raise ConfigError("no estimator named (-e NAME; see `graphpos estimators`)")
    if "truth" in names:
        raise ConfigError("'truth' is not an estimator name (the truth's exports are truth.*)")
    check_output_folder(args.output)  # before reading a long drive
    settings = estimator_settings(args, names)
    pose = initial_pose(args)
    drive = read_drive(args.drive)
    drive_warnings = require_usable(drive_checks(drive), str(args.drive))  # a nonsense drive: refused here
    range_model = load_range_model(args.range_model) if args.range_model else None
    from graphpos.cli.calibrate import profile as profile_of

    sensor_profile = profile_of(args)
    estimators = [make_estimator(n, settings=settings.get(n), layout=args.layout, range_model=range_model, initial_pose=pose,
                                 profile=sensor_profile) for n in names]
    blind = drive.without_truth()  # truth is for scoring only (issue 13)
    if args.layout:
        with naming_file(args.drive):
            drive.tags.layout(args.layout)  # a clear error for an unknown layout
    outcomes = {}
    for i, est in enumerate(estimators):
        outcomes[est.name] = _not_applicable(est, blind, args.drive)
        if outcomes[est.name] is None:
            progress_line("run", f"{est.name} ({i + 1} of {len(estimators)}) on {drive.name}, {drive.duration_s:.0f} s ...")
            outcomes[est.name] = _run_one(est, blind, args.drive)
    failed = {name: o for name, o in outcomes.items() if isinstance(o, Failure) and not o.not_applicable}
    skipped = {name: o for name, o in outcomes.items() if isinstance(o, Failure) and o.not_applicable}
    for name, failure in failed.items():
        print(error_line("run", f"{name} failed: {failure.error}"), file=sys.stderr)
    if len(failed) + len(skipped) == len(outcomes):  # nothing to write
        for failure in skipped.values():
            print(error_line("run", failure.error), file=sys.stderr)
        return 2 if all(f.traceback is None for f in failed.values()) else 1
    with output_folder(args.output, "run.json") as folder:
        _write_run(folder, args, drive, estimators, outcomes, settings, pose, sensor_profile, drive_warnings)
    for e in outcomes.values():
        if isinstance(e, Estimate):
            note = "  (not started: no start pose)" if e.diagnostics.get("not_started") else ""
            csv = one_line(str(args.output / f"{safe_name(e.name)}.csv"))
            print(f"{e.name:<18} {len(e):6d} outputs  {e.wall_time_s:7.3f} s  -> {csv}{note}")
            for line in e.diagnostics.get("warnings", []):  # e.g. a drive too short to calibrate the noise on
                print(warning_line("run", f"{e.name}: {line}"), file=sys.stderr)
            if e.diagnostics.get("not_started"):
                print(warning_line("run", f"{e.name}: {e.diagnostics['not_started']}"), file=sys.stderr)
    for failure in skipped.values():
        print(warning_line("run", f"not run: {failure.error}"), file=sys.stderr)
    for line in drive_warnings:  # last, so that a refusal stays one line
        print(warning_line("run", line), file=sys.stderr)
    return 1 if failed else 0


@dataclasses.dataclass
class Failure:
    """An estimator that raised, or that the drive lacks channels for (``not_applicable``): the one-line
    reason, and the traceback when it was a bug."""

    error: str
    traceback: str | None = None
    not_applicable: bool = False


def _not_applicable(est, drive, source: Path) -> "Failure | None":
    """Why ``est`` cannot run on ``drive`` (read from ``source``; a channel it needs is missing or empty), or None."""
    try:
        with naming_file(source):
            est.check(drive)
    except MissingChannelError as exc:
        return Failure(str(exc), not_applicable=True)
    return None


def _run_one(est, drive, source: Path) -> "Estimate | Failure":
    """``est.run(drive)``, or what went wrong (never raises but for an interrupt)."""
    try:
        with naming_file(source):
            return est.run(drive)
    except GraphposError as exc:
        return Failure(str(exc))
    except Exception as exc:  # a bug in one estimator must not cost the others their results
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return Failure(f"{type(exc).__name__}: {exc} (internal error at {Path(where.filename).name}:{where.lineno})",
                       traceback.format_exc())


def _write_run(folder: Path, args: argparse.Namespace, drive, estimators, outcomes, settings, pose, sensor_profile,
               drive_warnings: list[str]) -> None:
    """The files of ``run`` (module docstring) into ``folder``; ``drive_warnings``: the drive's broken
    warning rules (:func:`graphpos.io.checks.require_usable`)."""
    from graphpos.io.exports import write_atomically, write_exports
    from graphpos.registry import start_pose_record
    from graphpos.settings import config_dict

    write_exports(folder, drive, [e for e in outcomes.values() if isinstance(e, Estimate)])
    records = {}
    for est in estimators:
        e = outcomes[est.name]
        common = {"settings": settings.get(est.name, {}), "config": config_dict(est.config)}
        if isinstance(e, Failure):
            status = "not_applicable" if e.not_applicable else "failed"
            records[est.name] = {"status": status, "error": e.error, "traceback": e.traceback, **common}
            continue
        records[est.name] = {
            "status": "ok",
            "start": e.diagnostics.get("start"),
            "not_started": e.diagnostics.get("not_started"),
            "wall_time_s": e.wall_time_s,
            # wall time over drive time, as results.json and the reports' RTF (under 1: faster than real time)
            "real_time_factor": e.wall_time_s / drive.duration_s if drive.duration_s > 0 else None,
            "outputs": len(e),
            "rate_hz": e.rate_hz if e.rate_hz == e.rate_hz else None,
            "has_velocity": e.has_velocity,
            **common,
            "diagnostics": e.diagnostics,
        }
    summary = {
        "drive": str(args.drive),
        "drive_name": drive.name,
        "layout": args.layout,
        "range_model": str(args.range_model) if args.range_model else None,
        "initial_pose": start_pose_record(pose),
        "profile": sensor_profile.to_dict() if sensor_profile is not None else None,
        "failed": [name for name, e in outcomes.items() if isinstance(e, Failure) and not e.not_applicable],
        "not_applicable": [name for name, e in outcomes.items() if isinstance(e, Failure) and e.not_applicable],
        "drive_warnings": drive_warnings,
        "estimators": records,
    }
    write_atomically(folder / "run.json", json.dumps(summary, indent=1, default=float))
