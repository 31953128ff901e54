"""Commands ``estimators`` (list them) and ``run`` (estimators over one drive).

``graphpos run DRIVE.mcap -e NAME [-e NAME ...] [--layout L] [--range-model F] [--initial-pose E,N,YAW_DEG] --out-dir DIR``
writes into DIR:

- ``NAME.csv`` per estimator (:data:`graphpos.estimate.CSV_COLUMNS`, empty
  cells where the estimator does not estimate a quantity; only the header
  when it never started: no start pose given and none found in the drive);
- ``truth.csv``: the drive's truth at its own rate, same columns (when the
  drive has truth);
- ``run.json``: the start pose given, and each estimator's wall time, output
  rate, where it started (``start``, or ``not_started``) and diagnostics;
- ``estimates.mcap``: the drive with every estimate, for Foxglove.

The estimators see the drive without its truth (truth is for scoring only,
issue 13: :meth:`graphpos.drive.Drive.without_truth`). Every estimator runs
before anything is written, and each file is written through a temporary
file and a rename, so a bad input leaves no output.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from graphpos.errors import ConfigError, FileFormatError, naming_file
from graphpos.estimate import Estimate

if TYPE_CHECKING:
    from graphpos.ignition import StartPose


def register(sub) -> None:
    p = sub.add_parser("estimators", help="list the estimators",
                       description="Every estimator `graphpos run` knows: name, what it is, the channels it "
                                   "needs and the ones it uses when present.")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list of {name, summary, required_channels, optional_channels, config}")
    p.set_defaults(func=_estimators)

    p = sub.add_parser("run", help="run estimators over a drive",
                       description="Run one or more estimators over a drive and write their estimates "
                                   "(NAME.csv), the truth (truth.csv), run.json and estimates.mcap into a folder.")
    p.add_argument("drive", type=Path, metavar="DRIVE.mcap", help="drive file (see `graphpos simulate`)")
    p.add_argument("-e", "--estimator", dest="estimators", action="append", required=True, metavar="NAME",
                   help="estimator name (repeat for several; see `graphpos estimators`)")
    p.add_argument("--layout", metavar="L", help="use only the tags of this named layout (e.g. optimized)")
    p.add_argument("--range-model", type=Path, metavar="F",
                   help="range model JSON (from `graphpos ranging fit`); default: the drive's default model")
    p.add_argument("--out-dir", type=Path, required=True, metavar="DIR", help="output folder (created if absent)")
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
    import dataclasses

    from graphpos.registry import estimator_classes
    from graphpos.settings import config_dict

    rows = []
    for name, cls in estimator_classes().items():
        cfg = cls.default_config()
        rows.append({
            "name": name,
            "summary": cls.summary,
            "required_channels": list(cls.required_channels),
            "optional_channels": list(cls.optional_channels),
            "config": config_dict(cfg) if dataclasses.is_dataclass(cfg) else {},
        })
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        needs = ", ".join(r["required_channels"]) or "-"
        opt = f" (+ {', '.join(r['optional_channels'])})" if r["optional_channels"] else ""
        print(f"{r['name']:<18} needs {needs}{opt}")
        print(f"{'':<18} {r['summary']}")
    return 0


def truth_estimate(drive) -> Estimate:
    """The drive's truth as an :class:`Estimate` named ``truth`` (for CSV/MCAP output)."""
    tr = drive.truth
    return Estimate("truth", tr.t_s, tr.east_m, tr.north_m, tr.v_east_mps, tr.v_north_mps, tr.yaw_rad)


def _run(args: argparse.Namespace) -> int:
    from graphpos.io import read_drive, write_drive
    from graphpos.io.exports import csv_text, write_atomically
    from graphpos.ranging import load_range_model
    from graphpos.registry import make_estimator, start_pose_record
    from graphpos.settings import config_dict

    names = list(dict.fromkeys(args.estimators))
    if "truth" in names:
        raise ConfigError("'truth' is not an estimator name (truth.csv is always written)")
    if args.out_dir.exists() and not args.out_dir.is_dir():
        raise FileFormatError(f"{args.out_dir}: exists and is not a folder")
    settings = estimator_settings(args, names)  # before reading a long drive
    pose = initial_pose(args)
    drive = read_drive(args.drive)
    range_model = load_range_model(args.range_model) if args.range_model else None
    from graphpos.cli.calibrate import profile as profile_of

    sensor_profile = profile_of(args)
    estimators = [make_estimator(n, settings=settings.get(n), layout=args.layout, range_model=range_model, initial_pose=pose,
                                 profile=sensor_profile) for n in names]
    with naming_file(args.drive):
        if args.layout:
            drive.tags.layout(args.layout)  # a clear error for an unknown layout
        blind = drive.without_truth()  # truth is for scoring only (issue 13)
        estimates = [est.run(blind) for est in estimators]

    outputs: dict[str, str] = {f"{e.name}.csv": csv_text(e) for e in estimates}
    if drive.has("truth"):
        outputs["truth.csv"] = csv_text(truth_estimate(drive))
    summary = {
        "drive": str(args.drive),
        "drive_name": drive.name,
        "layout": args.layout,
        "range_model": str(args.range_model) if args.range_model else None,
        "initial_pose": start_pose_record(pose),
        "profile": sensor_profile.to_dict() if sensor_profile is not None else None,
        "estimators": {
            e.name: {
                "start": e.diagnostics.get("start"),
                "not_started": e.diagnostics.get("not_started"),
                "wall_time_s": e.wall_time_s,
                "realtime_factor": drive.duration_s / e.wall_time_s if e.wall_time_s > 0 else None,
                "outputs": len(e),
                "rate_hz": e.rate_hz if e.rate_hz == e.rate_hz else None,
                "has_velocity": e.has_velocity,
                "settings": settings.get(e.name, {}),
                "config": config_dict(est.config),
                "diagnostics": e.diagnostics,
            }
            for est, e in zip(estimators, estimates)
        },
    }
    outputs["run.json"] = json.dumps(summary, indent=1, default=float)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    write_drive(args.out_dir / "estimates.mcap", drive, estimates=estimates)
    for fname, text in outputs.items():
        write_atomically(args.out_dir / fname, text)
    for e in estimates:
        note = "  (not started: no start pose)" if e.diagnostics.get("not_started") else ""
        print(f"{e.name:<18} {len(e):6d} outputs  {e.wall_time_s:7.3f} s  -> {args.out_dir / (e.name + '.csv')}{note}")
    return 0
