"""Accuracy on recorded drives with the truth hidden from the estimators (issue 13).

Each drive is handed to the estimators as ``Drive.without_truth()`` with
default settings (the same for every drive); the output is scored against
the drive's truth afterwards. Prints RMS position error and ANEES per drive
and estimator (with, where graph-batch calibrated itself, the degrees of
freedom of its noise fit: ``noise_dof``), and each estimator's mean over
the drives of a dataset::

    python benchmarks/real_drives.py                       # Plaza1 + MRCLAM6 robots 1-5
    python benchmarks/real_drives.py -e graph-batch --plaza-only
    python benchmarks/real_drives.py --perturb             # Plaza1 + 0.3 deg/s gyro bias, truth heading +180 deg
    python benchmarks/real_drives.py --profile-from 1      # MRCLAM: graph-isam2, graph-batch with a profile calibrated on robot 1
    python benchmarks/real_drives.py --profile-from all    # ... with each robot's profile on every other: the matrix of ratios
    python benchmarks/real_drives.py --segments 150        # start-up: 150 s pieces beginning mid-drive
    python benchmarks/real_drives.py --halves 150          # short recordings: a profile from each drive's first half

Needs ``../shared/data`` beside the checkout (skips what is absent).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from eval.metrics import evaluate_estimate
from graphpos.errors import MissingChannelError
from graphpos.registry import make_estimator

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEFAULT_ESTIMATORS = ("fusion-ekf", "graph-isam2", "graph-batch")
#: Issue 13: graph-isam2 with another robot's profile within 15 % of its RMS with its own.
TRANSFER_TOLERANCE = 1.15


def plaza_drive(perturb: bool = False):
    from graphpos.io.plaza import import_plaza

    path = DATA / "plaza" / "Plaza1.mat"
    if not path.exists():
        return None
    drive = import_plaza(path)
    if perturb:
        drive = perturbed(drive)
    return drive


def perturbed(drive):
    """Plaza1 with a 0.3 deg/s gyro bias added and its truth heading turned by 180 degrees."""
    imu = drive.imu.replace(yaw_rate_radps=drive.imu.yaw_rate_radps + math.radians(0.3))
    truth = drive.truth.replace(yaw_rad=drive.truth.yaw_rad + math.pi)
    return drive.replace(name=drive.name + "-perturbed", channels={**drive.channels, "imu": imu, "truth": truth})


def mrclam_drives(robots=(1, 2, 3, 4, 5)):
    directory = DATA / "mrclam" / "MRCLAM_Dataset6"
    if not directory.exists():
        return []
    from graphpos.io.mrclam import import_mrclam

    return [import_mrclam(directory, robot) for robot in robots]


def score(drive, name: str, settings: dict | None = None, **kwargs) -> dict:
    est = make_estimator(name, settings, **kwargs)
    t0 = time.process_time()
    out = est.run(drive.without_truth())
    cpu = time.process_time() - t0
    whole = evaluate_estimate(drive, out)["windows"]["whole"]
    nees = whole.get("nees") or {}
    return {"rms_m": whole["position"]["rms_m"], "anees": nees.get("anees", float("nan")), "cpu_s": cpu, "estimate": out}


def _profile_of(drive, settings: dict | None = None):
    from graphpos.profile import SensorProfile

    est = make_estimator("graph-batch", settings).run(drive.without_truth())
    return SensorProfile.from_dict(est.diagnostics["profile"])


def _profile_transfer(sources: tuple[int, ...], robots: tuple[int, ...], settings_of) -> int:
    """graph-isam2 and graph-batch on each robot with each source robot's profile and with its own (RMS, ANEES).

    ``settings_of(drive, name)``: the settings an estimator gets on a drive
    (the calibrating graph-batch's too). With several sources, ends with
    graph-isam2's matrix of RMS ratios (profile from another robot / own
    profile) and how many of them exceed :data:`TRANSFER_TOLERANCE`.
    """
    drives = dict(zip(robots, mrclam_drives(robots)))
    missing = [r for r in sources if r not in drives]
    drives.update(zip(missing, mrclam_drives(tuple(missing))))
    if not drives:
        print("MRCLAM data not found under", DATA, file=sys.stderr)
        return 1
    profiles = {r: _profile_of(d, settings_of(d, "graph-batch")) for r, d in drives.items()}
    ratios: dict[tuple[int, int], float] = {}
    print(f"{'drive':<28}{'estimator':<14}{'profile of':>11}{'own rms_m':>10}{'anees':>8}{'given rms_m':>12}{'anees':>8}{'rms ratio':>10}")
    for r in robots:
        d = drives[r]
        for name in ("graph-isam2", "graph-batch"):
            own = score(d, name, settings_of(d, name), profile=profiles[r])
            for s in sources:
                if s == r:
                    continue
                other = score(d, name, settings_of(d, name), profile=profiles[s])
                ratio = other["rms_m"] / own["rms_m"]
                if name == "graph-isam2":
                    ratios[s, r] = ratio
                print(f"{d.name:<28}{name:<14}{'robot ' + str(s):>11}{own['rms_m']:>10.3f}{own['anees']:>8.2f}"
                      f"{other['rms_m']:>12.3f}{other['anees']:>8.2f}{ratio:>10.3f}", flush=True)
    if len(sources) > 1 and ratios:
        print("graph-isam2 RMS with the profile of (row) on (column) / with its own profile:")
        print(" " * 10 + "".join(f"{'robot ' + str(r):>9}" for r in robots))
        for s in sources:
            print(f"{'robot ' + str(s):<10}" + "".join(f"{ratios[s, r]:>9.3f}" if (s, r) in ratios else f"{'-':>9}" for r in robots))
        values = np.array(list(ratios.values()))
        print(f"{len(values)} pairs: median ratio {np.median(values):.3f}, worst {values.max():.3f}, "
              f"{int((values > TRANSFER_TOLERANCE).sum())} over {TRANSFER_TOLERANCE:g}")
    return 0


def _cut(drive, start_s: float, end_s: float, name: str):
    """The drive between two times, every channel cut alike (a recording that began and ended there)."""
    return drive.replace(name=name, channels={k: ch.between(start_s, end_s) for k, ch in drive.channels.items()})


#: Where the ``--segments`` pieces begin, as fractions of each drive's length.
SEGMENT_STARTS = (0.0, 0.15, 0.3, 0.45, 0.6, 0.75)


def _segments(groups: dict[str, list], names: list[str], length_s: float, settings_of) -> int:
    """Each estimator on pieces of each drive that begin mid-drive (a new start: moving, other landmarks first).

    Prints, per piece, how long after its beginning the first row came
    ("never" when the estimator did not start), the RMS and ANEES of its
    rows, and the degrees of freedom of its odometry noise fit where it
    calibrated itself (``noise_dof``; under
    :data:`~graphpos.graph.calibration.MIN_NOISE_FIT_DOF` the piece does not
    determine the noise); then per estimator the pieces never started and the mean delay
    (counting a piece never started as its whole length) and RMS. ``settings_of(drive,
    name)``: each estimator's settings (``--set``), as for :func:`_profile_transfer`.
    """
    print(f"{'piece':<34}{'estimator':<16}{'first_s':>8}{'rms_m':>8}{'anees':>9}{'noise_dof':>10}")
    summary: dict[str, list] = {n: [] for n in names}
    for drives in groups.values():
        for drive in drives:
            for f in SEGMENT_STARTS:
                a = drive.start_s + f * drive.duration_s
                piece = _cut(drive, a, a + length_s, f"{drive.name}@{f:.2f}")
                if len(piece.truth) < 2:
                    continue
                for name in names:
                    r = score(piece, name, settings_of(piece, name))
                    out = r["estimate"]
                    first = float(out.t_s[0] - a) if len(out.t_s) else math.nan
                    summary[name].append((first, r["rms_m"]))
                    shown = f"{first:>8.1f}" if len(out.t_s) else f"{'never':>8}"
                    dof = out.diagnostics.get("profile", {}).get("source", {}).get("noise_dof", math.nan)
                    print(f"{piece.name:<34}{name:<16}{shown}{r['rms_m']:>8.3f}{r['anees']:>9.2f}{dof:>10.1f}", flush=True)
    for name, rows in summary.items():
        first, rms = np.array(rows).T
        never = int(np.isnan(first).sum())
        print(f"{name}: {len(rows)} pieces of {length_s:.0f} s, {never} never started; first row after "
              f"{np.mean(np.where(np.isnan(first), length_s, first)):.1f} s on average; mean RMS {np.nanmean(rms):.3f} m")
    return 0


#: Where the ``--halves`` pieces begin, as fractions of each drive's length (all in its second half).
HALVES_STARTS = (0.55, 0.7, 0.85)


def _halves(groups: dict[str, list], names: list[str], length_s: float, settings_of) -> int:
    """The fleet workflow on short recordings: a profile calibrated on each drive's first half, used on pieces of its second.

    graph-batch calibrates (as ``graphpos calibrate``) on the first half of
    each drive; each estimator then runs on S-second pieces beginning at
    55, 70 and 85 % of the drive, on its own (self-calibrating or learning
    online from the piece alone) and with that profile (as ``--profile``).
    Prints RMS and ANEES per piece, then per estimator the mean RMS and
    median ANEES over the pieces where both started. ``settings_of``: as for
    :func:`_segments` (the calibrating graph-batch's too).
    """
    print(f"{'piece':<34}{'estimator':<16}{'own rms':>8}{'anees':>8}{'profile rms':>12}{'anees':>8}")
    summary: dict[str, list] = {n: [] for n in names}
    for drives in groups.values():
        for drive in drives:
            first_half = _cut(drive, drive.start_s, drive.start_s + 0.5 * drive.duration_s, drive.name + "-first-half")
            profile = _profile_of(first_half, settings_of(first_half, "graph-batch"))
            for f in HALVES_STARTS:
                a = drive.start_s + f * drive.duration_s
                piece = _cut(drive, a, a + length_s, f"{drive.name}@{f:.2f}")
                for name in names:
                    try:
                        own = score(piece, name, settings_of(piece, name))
                        given = score(piece, name, settings_of(piece, name), profile=profile)
                    except MissingChannelError as exc:  # a piece without a reading the estimator needs
                        print(f"{piece.name:<34}{name:<16}  cannot run: {exc}", flush=True)
                        continue
                    if not (len(own["estimate"].t_s) and len(given["estimate"].t_s)):
                        which = [w for w, r in (("on its own", own), ("with the profile", given)) if not len(r["estimate"].t_s)]
                        print(f"{piece.name:<34}{name:<16}  not started {' nor '.join(which)}", flush=True)
                        continue
                    summary[name].append((own["rms_m"], own["anees"], given["rms_m"], given["anees"]))
                    print(f"{piece.name:<34}{name:<16}{own['rms_m']:>8.3f}{own['anees']:>8.2f}{given['rms_m']:>12.3f}{given['anees']:>8.2f}", flush=True)
    for name, rows in summary.items():
        r = np.array(rows).reshape(-1, 4)
        print(f"{name}: {len(r)} pieces of {length_s:.0f} s; on its own mean RMS {np.mean(r[:, 0]):.3f} m, median ANEES {np.nanmedian(r[:, 1]):.2f}; "
              f"with the first half's profile {np.mean(r[:, 2]):.3f} m, {np.nanmedian(r[:, 3]):.2f}")
    return 0


def _has_setting(name: str, key: str) -> bool:
    from graphpos.registry import require_known
    from graphpos.settings import _has_setting as has

    return has(require_known([name])[name].default_config(), key)


def new_reading_rates(drive) -> dict[str, str]:
    """The rate settings the drive check ``held-readings`` suggests: each odometry channel that repeats its readings."""
    from graphpos.io.checks import held_readings

    return {setting: f"{new_hz:.3g}" for _, _, setting, _, new_hz in held_readings(drive)}


def _robot_or_all(text: str) -> int | str:
    if text == "all":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a robot number or 'all', not {text!r}") from None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-e", "--estimator", action="append", help="estimator (repeatable; default: %s)" % ", ".join(DEFAULT_ESTIMATORS))
    p.add_argument("--plaza-only", action="store_true")
    p.add_argument("--mrclam-only", action="store_true")
    p.add_argument("--robots", default="1,2,3,4,5")
    p.add_argument("--perturb", action="store_true", help="also Plaza1 with a 0.3 deg/s gyro bias and a reversed truth heading")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="estimator setting (for every estimator that has KEY)")
    p.add_argument("--new-reading-rates", action="store_true",
                   help="give each drive's estimators the rates of new readings that 'graphpos info' suggests for odometry "
                        "that repeats its readings (drive check held-readings), as a user would")
    p.add_argument("--profile-from", type=_robot_or_all, metavar="N|all",
                   help="MRCLAM: graph-isam2 and graph-batch on every robot with the profile graph-batch calibrates on robot N "
                        "(all: on each of the robots in turn, and the matrix of ratios), against its own drive's")
    p.add_argument("--segments", type=float, metavar="S",
                   help="start-up instead: each estimator on S-second pieces beginning at 0, 15, ... 75 %% of each drive")
    p.add_argument("--halves", type=float, metavar="S",
                   help="short recordings instead: each estimator on S-second pieces of each drive's second half, on its own "
                        "and with the profile graph-batch calibrates on the first half")
    args = p.parse_args(argv)
    names = args.estimator or list(DEFAULT_ESTIMATORS)
    settings = dict(s.split("=", 1) for s in args.set)

    def settings_of(drive, name: str) -> dict | None:
        given = {**(new_reading_rates(drive) if args.new_reading_rates else {}), **settings}
        return {k: v for k, v in given.items() if _has_setting(name, k)} or None

    if args.profile_from is not None:
        robots = tuple(int(r) for r in args.robots.split(","))
        sources = robots if args.profile_from == "all" else (args.profile_from,)
        return _profile_transfer(sources, robots, settings_of)
    groups: dict[str, list] = {}
    if not args.mrclam_only:
        d = plaza_drive()
        if d is not None:
            groups["plaza"] = [d]
        if args.perturb and d is not None:
            groups["plaza-perturbed"] = [perturbed(d)]
    if not args.plaza_only:
        robots = tuple(int(r) for r in args.robots.split(","))
        drives = mrclam_drives(robots)
        if drives:
            groups["mrclam6"] = drives
    if not groups:
        print("no recorded drives found under", DATA, file=sys.stderr)
        return 1
    if args.segments is not None:
        return _segments(groups, names, args.segments, settings_of)
    if args.halves is not None:
        return _halves(groups, names, args.halves, settings_of)
    print(f"{'drive':<28}{'estimator':<16}{'rms_m':>8}{'anees':>9}{'cpu_s':>8}{'noise_dof':>10}")
    for group, drives in groups.items():
        means: dict[str, list] = {n: [] for n in names}
        for drive in drives:
            for name in names:
                try:
                    r = score(drive, name, settings_of(drive, name))
                except Exception as exc:  # noqa: BLE001 - a benchmark reports and goes on
                    print(f"{drive.name:<28}{name:<16}  failed: {str(exc)[:120]}")
                    means[name].append(float("nan"))
                    continue
                means[name].append(r["rms_m"])
                dof = r["estimate"].diagnostics.get("profile", {}).get("source", {}).get("noise_dof", math.nan)
                print(f"{drive.name:<28}{name:<16}{r['rms_m']:>8.3f}{r['anees']:>9.2f}{r['cpu_s']:>8.1f}{dof:>10.1f}", flush=True)
        for name in names:
            print(f"{'mean ' + group:<28}{name:<16}{np.mean(means[name]):>8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
