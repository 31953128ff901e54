"""Command ``calibrate``: a drive's sensor profile, found without its truth, for the next drives of the same sensors.

``graphpos calibrate DRIVE.mcap -o profile.json`` runs graph-batch's
self-calibration (:func:`graphpos.graph.calibration.fit_profile`) on the drive
without its truth and saves the :class:`~graphpos.profile.SensorProfile`
(gyro bias, turn-rate and wheel scales, range scale, offset and sigma, noise
levels). ``graphpos run|evaluate ... --profile profile.json`` then corrects
another drive's readings with it before any estimator sees them, so an
online estimator starts calibrated.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from graphpos.cli import add_output_option, one_line, progress_line, warning_line


def register(sub) -> None:
    p = sub.add_parser("calibrate",
                       description="Self-calibrate the drive's sensors with graph-batch (truth hidden) and save the "
                                   "sensor profile as JSON, for --profile on run and evaluate.")
    p.add_argument("drive", type=Path, metavar="DRIVE.mcap", help="drive file")
    add_output_option(p, "PROFILE.json", "profile file to write", "--output")
    p.add_argument("--layout", metavar="L", help="use only the tags of this named layout")
    from graphpos.cli.estimators import add_initial_pose_option

    add_initial_pose_option(p)
    p.set_defaults(func=_calibrate)


def add_profile_option(p: argparse.ArgumentParser) -> None:
    """``--profile``, read back by :func:`profile`."""
    p.add_argument("--profile", type=Path, default=None, metavar="PROFILE.json",
                   help="sensor profile from `graphpos calibrate` on another drive of the same sensors: readings "
                        "are corrected with it and its noise levels used (default: none; graph-batch then "
                        "calibrates itself)")


def profile(args: argparse.Namespace):
    """The :class:`~graphpos.profile.SensorProfile` of ``--profile``, or None."""
    from graphpos.profile import SensorProfile

    path = getattr(args, "profile", None)
    return None if path is None else SensorProfile.load(path)


def _calibrate(args: argparse.Namespace) -> int:
    from graphpos.cli.estimators import initial_pose
    from graphpos.errors import EstimationError, naming_file
    from graphpos.graph import ESTIMATORS
    from graphpos.io import read_drive
    from graphpos.io.outputs import check_output_file
    from graphpos.profile import SensorProfile

    check_output_file(args.output, inputs={"drive": args.drive}, kind="json")
    pose = initial_pose(args)
    drive = read_drive(args.drive)
    with naming_file(args.drive):
        if args.layout:
            drive.tags.layout(args.layout)
        progress_line("calibrate", f"self-calibrating graph-batch on {drive.name} ({drive.duration_s:.0f} s: two or three solves) ...")
        est = ESTIMATORS["graph-batch"](layout=args.layout, initial_pose=pose).run(drive.without_truth())
    if "profile" not in est.diagnostics:
        raise EstimationError(f"{args.drive}: no profile found: {est.diagnostics.get('not_started', 'the drive has no odometry to calibrate')}")
    found = SensorProfile.from_dict(est.diagnostics["profile"])
    found.save(args.output)
    print(f"wrote {one_line(str(args.output))}: {_summary(found)}")
    for line in est.diagnostics.get("warnings", []):  # e.g. a drive too short to determine the noise (as run prints them)
        print(warning_line("calibrate", line), file=sys.stderr)
    return 0


def _summary(found: SensorProfile) -> str:
    """Every term of a profile that a user reads to judge it, in the units they think in."""
    sigma = "the range model's" if found.range_sigma0_m is None else f"{found.range_sigma0_m:.3f} m"
    return (f"gyro bias {math.degrees(found.gyro_bias_radps):+.3f} deg/s, yaw-rate scale {found.yaw_rate_scale:.4f}, "
            f"wheel scale {found.wheel_scale:.4f}, compass bias {math.degrees(found.compass_bias_rad):+.2f} deg, "
            f"range scale {found.range_scale:.4f}, offset {found.range_offset_m:+.3f} m, sigma {sigma}, "
            f"reader delay {found.range_delay_s:.2f} s")
