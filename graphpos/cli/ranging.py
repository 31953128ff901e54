"""Commands ``ranging table1``, ``ranging fit``, ``ranging check`` and ``ranging show`` (the ``graphpos.ranging`` package)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from graphpos.cli import add_output_option, one_line
from graphpos.errors import ConfigError, naming_file
from graphpos.io.outputs import check_output_file


def register(sub) -> None:
    group = sub.add_parser("ranging",
                           description="LSSVM and propagation models from RSS to distance (song2016), and "
                                       "the linear calibration of reported ranges.")
    commands = group.add_subparsers(dest="ranging_command", required=True, parser_class=type(group))

    p = commands.add_parser("table1", help="song2016 Table 1 on simulated calibration data",
                            description="Mean and STD of the fitting errors of LSSVM and the propagation model "
                                        "in the laboratory, outdoor and tunnel environments, beside the "
                                        "published Table 1, in metres and in RSS units (the paper's units are unstated), with "
                                        "the LSSVM/propagation STD ratio beside the paper's (see "
                                        "graphpos/ranging/table1.py for what the error is measured in).")
    p.add_argument("--seed", type=int, default=None, help="seed of the simulated collections (default 2016)")
    p.add_argument("--json", action="store_true",
                   help="print {environment: {lssvm: {mean, std, ...}, propagation: {...}}} as JSON")
    p.add_argument("--plot", type=Path, default=None, metavar="FILE.png",
                   help="also write the fitted curves and distance errors (song2016 Fig. 6 and 7)")
    p.set_defaults(func=_table1)

    p = commands.add_parser("fit", help="fit a range model to a drive with truth",
                            description="Fit a range model to a drive's RFID readings against its true ranges "
                                        "(rfid.true_range_m, or the truth trajectory and the tag map) and save "
                                        "it as JSON for `--range-model`.")
    p.add_argument("drive", type=Path, help="drive MCAP file with truth")
    p.add_argument("--truth", action="store_true",
                   help="fit against the drive's truth (required: a range model is fitted to true distances)")
    add_output_option(p, "MODEL.json", "model file to write (JSON)", "--output")
    p.add_argument("--kind", default="auto", choices=("auto", "lssvm", "propagation", "linear"),
                   help="auto: linear for radios reporting ranges, lssvm for RSS (default)")
    p.set_defaults(func=_fit)

    p = commands.add_parser("check", help="range error of a range model on a drive with truth",
                            description="Mean, STD and RMS of the range error (predicted - true) by true-distance "
                                        "band, and how honest the model's 1-sigma is (RMS of error/sigma).")
    p.add_argument("drive", type=Path, help="drive MCAP file with truth")
    p.add_argument("--range-model", type=Path, default=None, metavar="FILE",
                   help="saved range model (default: the drive's default model)")
    p.set_defaults(func=_check)

    p = commands.add_parser("show", help="print a saved range model",
                            description="Kind, parameters and predicted 1-sigma of a saved range model.")
    p.add_argument("model", type=Path, help="range-model JSON file")
    p.set_defaults(func=_show)


def _table1(args: argparse.Namespace) -> int:
    from graphpos.ranging.drive_models import CALIBRATION_SEED
    from graphpos.ranging.table1 import format_table1, table1

    seed = CALIBRATION_SEED if args.seed is None else args.seed
    if seed < 0:
        raise ConfigError(f"--seed must be non-negative, got {seed}")
    if args.plot is not None:
        check_output_file(args.plot, kind="png")
    figures = table1(seed)
    print(json.dumps(figures, indent=1) if args.json else format_table1(figures, seed))
    if args.plot is not None:
        from graphpos.ranging.figures import plot_calibration

        plot_calibration(seed, args.plot)
        # with --json, stdout is the JSON document alone
        print(f"wrote {one_line(str(args.plot))}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _error_figures(predicted_m: np.ndarray, true_m: np.ndarray) -> str:
    e = predicted_m - true_m
    e = e[np.isfinite(e)]
    return f"mean {e.mean():.3f} m, STD {e.std():.3f} m, RMS {np.sqrt(np.mean(e**2)):.3f} m ({e.size} readings)"


def _fit(args: argparse.Namespace) -> int:
    from graphpos.io import read_drive
    from graphpos.ranging import fit_from_drive, true_ranges_m

    if not args.truth:
        raise ConfigError("a range model is fitted to true distances: pass --truth to fit against the drive's truth")
    check_output_file(args.output, inputs={"drive": args.drive}, kind="json")
    drive = read_drive(args.drive)
    with naming_file(args.drive):
        model = fit_from_drive(drive, args.kind)
        true_m = true_ranges_m(drive)
    reading = drive.rfid[model.input_column]
    params = {k: v for k, v in model.to_dict().items() if np.isscalar(v)}
    print(f"{model.kind} range model fitted to {args.drive.name}: "
          + ", ".join(f"{k} {v:.6g}" if isinstance(v, float) else f"{k} {v}" for k, v in params.items()))
    if model.input_column == "range_m":
        print(f"  reported range - true range: {_error_figures(reading, true_m)}")
    print(f"  fitted range - true range (in-sample): {_error_figures(model.predict_distance_m(reading), true_m)}")
    model.save(args.output)
    print(f"wrote {one_line(str(args.output))}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from graphpos.io import read_drive
    from graphpos.ranging import default_range_model, load_range_model
    from graphpos.ranging.assess import format_range_errors, range_errors

    model = load_range_model(args.range_model) if args.range_model else None
    drive = read_drive(args.drive)
    with naming_file(args.drive):
        if model is None:
            model = default_range_model(drive)
        errors = format_range_errors(range_errors(model, drive))
    source = args.range_model or "default"
    print(f"{model.kind} range model ({source}) on {args.drive.name}: range error (m) by true range")
    print(errors)
    return 0


def _show(args: argparse.Namespace) -> int:
    from graphpos.ranging import load_range_model

    model = load_range_model(args.model)
    params = {k: v for k, v in model.to_dict().items() if np.isscalar(v)}
    print(f"{args.model}: {model.kind} range model reading rfid.{model.input_column}")
    for key, value in params.items():
        print(f"  {key}: {value}")
    distances = np.array([0.5, 1.0, 2.0, 4.0, 6.0, 9.0, 20.0, 50.0])
    sigmas = model.predict_sigma_m(distances)
    print("  1-sigma: " + ", ".join(f"{s:.2f} m at {d:g} m" for d, s in zip(distances, sigmas)))
    return 0
