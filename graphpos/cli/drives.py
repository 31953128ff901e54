"""Commands ``info`` and ``import plaza|mrclam|rosbag|csv`` (drive files, ``graphpos.io``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from graphpos.cli import add_output_option, one_line, warning_line


def register(sub) -> None:
    p = sub.add_parser("info",
                       description="Channels (rows, rate, time span), tags and layouts, RSUs, windows, origin, "
                                   "parameters and stored estimates of a drive MCAP file. rate_hz counts distinct "
                                   "timestamps per second: (distinct times - 1) / (last - first). The checks "
                                   "section lists every rule of what is refused (error: run and evaluate refuse "
                                   "the drive, and info exits with status 2 after printing) and what is warned "
                                   "about (warning: said on stderr).")
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="drive file")
    p.add_argument("--json", action="store_true",
                   help="print JSON: duration_s, channels {name: {count, rate_hz, start_s, end_s}}, "
                        "tags {count, layouts}, rsus, windows, origin, params, estimates, checks [{name, level, "
                        "rule, checked, verdict, message}], and with truth "
                        "truth_checks {heading, ranges, odometry, turn}")
    p.set_defaults(func=_info)

    group = sub.add_parser("import",
                           description="Convert a recorded dataset into a drive MCAP file.")
    formats = group.add_subparsers(dest="import_format", required=True, parser_class=type(group))
    p = formats.add_parser("plaza", help="a CMU Plaza range-only dataset (.mat with GT, DR, TD, TL)",
                           description="Beacons -> tags, UWB ranges -> rfid range_m (uncorrected), odometry "
                                       "increments -> wheel speed and yaw rate, GT -> truth. Conventions: "
                                       "graphpos/io/plaza.py.")
    p.add_argument("file", type=Path, metavar="FILE.mat", help="the Plaza .mat file")
    add_output_option(p, "FILE.mcap", "output drive file", "--output")
    p.add_argument("--origin", type=_origin, default=None, metavar="LAT,LON[,ALT]",
                   help="geodetic origin of the dataset's x/y frame in degrees (and metres), for map views "
                        "(default: the CMU campus, approximately)")
    p.set_defaults(func=_import_plaza)
    p = formats.add_parser("mrclam", help="one robot of a UTIAS MRCLAM dataset (folder of .dat files)",
                           description="Landmarks -> tags, camera ranges to landmarks -> rfid range_m "
                                       "(uncorrected; sightings of robots dropped), odometry -> wheel speed and "
                                       "yaw rate, Vicon -> truth; times stay Unix seconds. Conventions: "
                                       "graphpos/io/mrclam.py.")
    p.add_argument("directory", type=Path, metavar="DIR", help="the dataset folder (e.g. MRCLAM_Dataset6)")
    p.add_argument("--robot", type=int, required=True, metavar="N", help="robot number, 1-5")
    add_output_option(p, "FILE.mcap", "output drive file", "--output")
    p.add_argument("--origin", type=_origin, default=None, metavar="LAT,LON[,ALT]",
                   help="geodetic origin of the dataset's x/y frame in degrees (and metres), for map views "
                        "(default: UTIAS, Toronto, approximately)")
    p.set_defaults(func=_import_mrclam)
    p = formats.add_parser("rosbag", help="a ROS 1 or ROS 2 bag, read through a mapping file",
                           description="Topics -> channels as the mapping file says (a TOML file; example: "
                                       "examples/mapping_rosbag.toml; format: graphpos/io/mapping.py). Header "
                                       "stamps are the measurement times, record times the arrival times.")
    p.add_argument("source", type=Path, metavar="BAG",
                   help="a ROS 1 .bag file, or a ROS 2 bag folder (or the .db3/.mcap file in it)")
    p.add_argument("--mapping", type=Path, required=True, metavar="MAPPING.toml", help="the mapping file")
    add_output_option(p, "FILE.mcap", "output drive file", "--output")
    p.set_defaults(func=_import_mapped)
    p = formats.add_parser("csv", help="CSV logs, read through a mapping file",
                           description="Columns -> channels as the mapping file says (a TOML file; example: "
                                       "examples/mapping_csv.toml; format: graphpos/io/mapping.py).")
    p.add_argument("source", type=Path, metavar="DIR", help="the folder holding the CSV files the mapping names")
    p.add_argument("--mapping", type=Path, required=True, metavar="MAPPING.toml", help="the mapping file")
    add_output_option(p, "FILE.mcap", "output drive file", "--output")
    p.set_defaults(func=_import_mapped)


def _origin(text: str):
    from graphpos.drive import GeoOrigin
    from graphpos.errors import DriveError

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (2, 3):
        raise argparse.ArgumentTypeError(f"expected LAT,LON[,ALT] in degrees (and metres), got '{text}'")
    try:
        return GeoOrigin(*values)  # checked against graphpos.drive.ORIGIN_SPECS
    except DriveError as exc:
        raise argparse.ArgumentTypeError(f"expected LAT,LON[,ALT] in degrees (and metres), got '{text}': {exc.reason}") from None


def _rate_hz(t_s: np.ndarray) -> float | None:
    times = np.unique(t_s)
    if times.size < 2 or times[-1] == times[0]:
        return None
    return float((times.size - 1) / (times[-1] - times[0]))


def drive_summary(path: Path) -> dict[str, Any]:
    """What ``info --json`` prints for a drive file.

    ``checks``: the drive against every rule of what is refused and what is
    warned about (:func:`graphpos.io.checks.drive_checks`). With a
    ``truth`` channel it has ``truth_checks``: the drive's sensors and truth
    checked against each other (:func:`graphpos.io.checks.truth_checks`).
    """
    from graphpos.io import read_mcap
    from graphpos.io.checks import drive_checks, truth_checks

    drive, estimates = read_mcap(path)
    channels = {
        name: {
            "count": len(ch),
            "rate_hz": _rate_hz(ch.t_s),
            "start_s": float(ch.t_s[0]) if len(ch) else None,
            "end_s": float(ch.t_s[-1]) if len(ch) else None,
        }
        for name, ch in drive.channels.items()
    }
    summary = {
        "file": str(path),
        "name": drive.name,
        "duration_s": drive.duration_s,
        "start_s": drive.start_s,
        "end_s": drive.end_s,
        "channels": channels,
        "tags": {"count": len(drive.tags), "layouts": {k: int(v.size) for k, v in drive.tags.layouts.items()}},
        "rsus": {"count": len(drive.rsus)},
        "windows": [{"label": w.label, "start_s": w.start_s, "end_s": w.end_s} for w in drive.windows],
        "origin": {"lat_deg": drive.origin.lat_deg, "lon_deg": drive.origin.lon_deg, "alt_m": drive.origin.alt_m},
        "params": drive.params,
        "estimates": {e.name: {"count": len(e), "rate_hz": e.rate_hz if np.isfinite(e.rate_hz) else None} for e in estimates},
        "checks": drive_checks(drive),
    }
    checks = truth_checks(drive)
    if checks:
        summary["truth_checks"] = checks
    return summary


def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def _table_lines(rows: list[list[str]], right: list[bool], indent: str = "", last_free: bool = False) -> list[str]:
    """Rows of cells as lines of aligned columns, each as wide as its widest cell, two spaces apart.

    Parameters
    ----------
    rows : list of list of str
        The cells, a header row first where there is one.
    right : list of bool
        Per column: right-aligned (numbers) or left-aligned.
    indent : str
        Put before every line.
    last_free : bool
        The last column (free text) is not padded.
    """
    widths = [max(len(row[i]) for row in rows) for i in range(len(right))]
    if last_free:
        widths[-1] = 0
    return [indent + "  ".join((cell.rjust(w) if r else cell.ljust(w)) for cell, w, r in zip(row, widths, right)).rstrip()
            for row in rows]


def _info(args: argparse.Namespace) -> int:
    from graphpos.io.checks import require_usable

    info = drive_summary(args.file)
    if args.json:
        print(json.dumps(info, indent=1))
    else:
        _print_info(info)
    for line in require_usable(info["checks"], str(args.file)):
        print(warning_line("info", line), file=sys.stderr)
    return 0


def _print_info(info: dict[str, Any]) -> None:
    print(f"drive     {info['name']}  ({info['file']})")
    print(f"duration  {info['duration_s']:.3f} s  ({info['start_s']:.3f} .. {info['end_s']:.3f} s)")
    channel_rows = [["channel", "rows", "rate_hz", "start_s", "end_s"]]
    channel_rows += [[name, str(ch["count"]), _num(ch["rate_hz"], ".2f"), _num(ch["start_s"], ".3f"),
                      _num(ch["end_s"], ".3f")] for name, ch in info["channels"].items()]
    print("\n".join(_table_lines(channel_rows, [False, True, True, True, True])))
    layouts = ", ".join(f"{k} {v}" for k, v in info["tags"]["layouts"].items())
    print(f"tags      {info['tags']['count']}  (layouts: {layouts})")
    print(f"rsus      {info['rsus']['count']}")
    windows = ", ".join(f"{w['label']} [{w['start_s']:.1f}, {w['end_s']:.1f}] s" for w in info["windows"])
    print(f"windows   {windows or 'none'}")
    o = info["origin"]
    print(f"origin    lat {o['lat_deg']:.6f}, lon {o['lon_deg']:.6f}, alt {o['alt_m']:.1f} m")
    print(f"params    {json.dumps(info['params'])}")
    if info["estimates"]:
        print("estimates " + ", ".join(f"{k} ({v['count']} rows)" for k, v in info["estimates"].items()))
    print("checks (error: run and evaluate refuse the drive; warning: they say so)")
    check_rows = [[c["name"], c["level"], c["verdict"], c["checked"], c["message"] or c["rule"]] for c in info["checks"]]
    if check_rows:
        print("\n".join(_table_lines(check_rows, [False] * 5, indent="  ", last_free=True)))
    if info.get("truth_checks"):
        from graphpos.io.checks import describe_check

        print("truth checks (sensors and truth against each other)")
        for name, check in info["truth_checks"].items():
            print(f"  {name:<10}{check['verdict']}: {describe_check(name, check)}")


def _import_plaza(args: argparse.Namespace) -> int:
    from graphpos.io import write_drive
    from graphpos.io.outputs import check_output_file
    from graphpos.io.plaza import import_plaza

    check_output_file(args.output, inputs={"Plaza file": args.file}, kind="mcap")
    drive = import_plaza(args.file) if args.origin is None else import_plaza(args.file, origin=args.origin)
    write_drive(args.output, drive)
    counts = ", ".join(f"{name} {len(ch)}" for name, ch in drive.channels.items())
    print(f"wrote {one_line(str(args.output))}: {drive.name}, {drive.duration_s:.1f} s, {len(drive.tags)} beacons ({counts})")
    for note in drive.params.get("import_notes", []):
        print(warning_line(args.command, note), file=sys.stderr)
    return 0


def _import_mrclam(args: argparse.Namespace) -> int:
    from graphpos.io import write_drive
    from graphpos.io.mrclam import import_mrclam
    from graphpos.io.outputs import check_output_file

    check_output_file(args.output, inputs={"dataset folder": args.directory}, kind="mcap")
    if args.origin is None:
        drive = import_mrclam(args.directory, args.robot)
    else:
        drive = import_mrclam(args.directory, args.robot, origin=args.origin)
    write_drive(args.output, drive)
    counts = ", ".join(f"{name} {len(ch)}" for name, ch in drive.channels.items())
    p = drive.params
    dropped = (f"dropped {p['sightings_of_robots_dropped']} robot sightings, "
               f"{p['sightings_of_unknown_barcodes_dropped'] + p['sightings_of_unsurveyed_subjects_dropped']} "
               f"unknown, {p['odometry_repeated_stamps_dropped']} repeated odometry stamps")
    print(f"wrote {one_line(str(args.output))}: {drive.name}, {drive.duration_s:.1f} s, {len(drive.tags)} landmarks ({counts}); {dropped}")
    return 0


def _import_mapped(args: argparse.Namespace) -> int:
    """``import rosbag`` and ``import csv``: a recording read through a mapping file."""
    from graphpos.io import write_drive
    from graphpos.io.outputs import check_output_file

    if args.import_format == "rosbag":
        from graphpos.io.rosbag import import_rosbag as read
    else:
        from graphpos.io.csvlog import import_csv as read
    source = "bag" if args.import_format == "rosbag" else "CSV folder"
    check_output_file(args.output, inputs={source: args.source, "mapping file": args.mapping}, kind="mcap")
    drive = read(args.source, args.mapping)
    write_drive(args.output, drive)
    counts = ", ".join(f"{name} {len(ch)}" for name, ch in drive.channels.items())
    print(f"wrote {one_line(str(args.output))}: {drive.name}, {drive.duration_s:.1f} s, {len(drive.tags)} tags, "
          f"{len(drive.rsus)} RSUs ({counts})")
    for note in drive.params.get("import_notes", []):
        print(warning_line(args.command, note), file=sys.stderr)
    return 0
