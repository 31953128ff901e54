"""Importer of the CMU Plaza range-only datasets (Djugash et al.).

A Plaza ``.mat`` file holds five arrays; their meaning, checked against
Plaza1 (see ``tests/io/test_plaza.py``):

``GT`` (N, 4) ``[t_s, x_m, y_m, heading_rad]``
    Ground truth. The heading is measured from the x axis, counter-clockwise:
    the direction of motion ``atan2(dy, dx)`` matches it within about 0.016
    rad (median) wherever the robot moves. Taking x as east and y as north,
    it is the project's yaw. It is stored wrapped (Plaza1: within
    [-pi/2, 3pi/2), with five 2pi jumps); it is unwrapped here. Other runs
    do not all follow that convention (one has a heading 180 deg from the
    direction of motion), so the importer checks it
    (:func:`graphpos.io.checks.heading_check`): a heading about 180 deg
    off is corrected (pi added; its rate, and so ``DR``, is unchanged) and
    one that drifts from the motion or is otherwise inconsistent with it is
    kept as recorded; either way a note goes into the drive's
    ``params["import_notes"]`` (``graphpos import plaza`` prints it as a
    warning). Plaza1 passes the check and is left alone.
``DR`` (N-1, 3) ``[t_s, distance_m, heading_change_rad]``
    Odometry increments from ``GT`` row k to row k+1, stamped with the time
    of row k+1. The heading changes are exactly the differences of ``GT``'s
    heading (the dataset's heading comes from the same gyro), so a yaw rate
    made from them is a near-perfect gyro. They are taken modulo 2pi into
    [-pi, pi) (Plaza1's already are), as a change of a wrapped heading.
``DRp`` (N, 4)
    A dead-reckoned path from the data's authors. Its step lengths equal
    ``DR``'s distances but its step directions drift away from the heading
    (0.58 rad by the end of Plaza1), so it is not imported.
``TD`` (K, 4) ``[t_s, antenna_id, beacon_id, range_m]``
    UWB ranges from the robot's radio (``antenna_id``, 2 in Plaza1) to a
    beacon. Rows are not all in time order (Plaza1 has two jumps back of
    50-64 s); they are sorted by time (stable). Plaza1's ranges read about
    1.069 x the true distance; the importer does not correct that
    (calibration is the ranging layer's job).
``TL`` (B, 3) ``[beacon_id, x_m, y_m]``
    Surveyed beacon positions.

Times are the recording's own clock in seconds (Plaza1: 3856.9-5790.3 s),
kept as they are.

The drive has:

- ``truth``: ``GT`` positions and unwrapped heading (corrected when
  reversed, above); velocity by
  differentiating the positions (``numpy.gradient``, second order, uneven
  spacing); yaw rate and accelerations NaN.
- ``wheel``: ``speed_mps = distance / dt`` of each ``DR`` row;
- ``imu``: ``yaw_rate_radps = heading_change / dt``; accelerometer columns
  NaN (the dataset has none);
  both stamped at the middle of their interval, where a mean rate over the
  interval is the best estimate of the rate (the first row's interval is
  taken as long as the second's);
- ``rfid``: one row per ``TD`` row: ``tag_id`` = beacon id, ``range_m``
  as recorded, ``rss`` NaN, ``true_range_m`` the distance from the ground
  truth position (interpolated at the reading time; NaN outside ``GT``'s
  time span) to the beacon — truth, for evaluating ranging;
- ``tags``: one per ``TL`` row, ``wall_side`` 0, ``group`` -1, layout
  ``dense`` only;
- ``params["import_notes"]``: what the importer found wrong and did about
  it, one sentence each (absent when nothing was).

The geodetic origin defaults to an approximate position of the CMU campus
(the dataset has no geodetic reference); it only places the track on a map.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import scipy.io

from graphpos.drive import Channel, Drive, GeoOrigin, TagMap, truth_from_poses
from graphpos.errors import DriveError, FileFormatError
from graphpos.io.checks import heading_check
from graphpos.io.files import read_input

#: Approximate geodetic position of the Plaza datasets (CMU campus, Pittsburgh).
PLAZA_ORIGIN = GeoOrigin(lat_deg=40.4435, lon_deg=-79.9435, alt_m=280.0)
#: Where the data comes from, said when the file is missing: GTSAM's Plaza1_.mat is, byte for byte, the
#: Plaza1.mat of ../shared/data/plaza (SHA-256 9ccbfec1...).
PLAZA_SOURCE = ("the CMU Plaza files ship in the GTSAM repository, github.com/borglab/gtsam: "
                "examples/Data/Plaza1_.mat and Plaza2_.mat")

#: Arrays read from the file, with their minimum column count and meaning.
_ARRAYS = {
    "GT": (4, "[t_s, x_m, y_m, heading_rad]"),
    "DR": (3, "[t_s, distance_m, heading_change_rad]"),
    "TD": (4, "[t_s, antenna_id, beacon_id, range_m]"),
    "TL": (3, "[beacon_id, x_m, y_m]"),
}


def _load(path: Path) -> dict[str, np.ndarray]:
    if not path.exists() and not path.is_symlink():
        raise FileFormatError(f"{path}: no such file ({PLAZA_SOURCE})")
    raw = read_input(path)
    try:
        mat = scipy.io.loadmat(io.BytesIO(raw))
    except NotImplementedError:
        raise FileFormatError(f"{path}: MATLAB v7.3 (HDF5) files are not supported; save it with -v7") from None
    except Exception as exc:  # noqa: BLE001 - scipy raises many types on a file that is not a .mat
        raise FileFormatError(f"{path}: not a readable MATLAB .mat file ({type(exc).__name__}: {exc})") from None
    arrays = {}
    for name, (min_cols, meaning) in _ARRAYS.items():
        if name not in mat:
            found = sorted(k for k in mat if not k.startswith("__"))
            raise FileFormatError(f"{path}: no array '{name}' {meaning} (found: {', '.join(found) or 'none'}); not a Plaza dataset?")
        arr = mat[name]
        min_rows = 2 if name in ("GT", "DR") else 1
        if not (
            isinstance(arr, np.ndarray)
            and arr.ndim == 2
            and arr.shape[1] >= min_cols
            and arr.shape[0] >= min_rows
            and np.issubdtype(arr.dtype, np.number)
            and not np.iscomplexobj(arr)
        ):
            shape = getattr(arr, "shape", None)
            raise FileFormatError(
                f"{path}: array '{name}' has shape {shape} and type {getattr(arr, 'dtype', type(arr).__name__)}; "
                f"expected a real matrix with at least {min_rows} rows of {min_cols} columns {meaning}"
            )
        arrays[name] = np.asarray(arr[:, :min_cols], dtype=np.float64)
    return arrays


def _rates(dr: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mid-interval times, speed and yaw rate of the odometry increments."""
    t_end = dr[:, 0]
    dt = np.diff(t_end)
    if not np.all(dt > 0):
        row = int(np.argmax(~(dt > 0))) + 1
        raise FileFormatError(f"{path}: array 'DR' row {row}: time {float(t_end[row])!r} does not increase")
    dt = np.r_[dt[0], dt]
    turn = np.remainder(dr[:, 2] + np.pi, 2 * np.pi) - np.pi  # an increment of a wrapped heading
    return t_end - dt / 2, dr[:, 1] / dt, turn / dt


def _truth(gt: np.ndarray, path: Path) -> Channel:
    t = gt[:, 0]
    if not np.all(np.diff(t) > 0):
        row = int(np.argmax(~(np.diff(t) > 0))) + 1
        raise FileFormatError(f"{path}: array 'GT' row {row}: time {float(t[row])!r} does not increase")
    east, north = gt[:, 1], gt[:, 2]
    return truth_from_poses(t, east, north, gt[:, 3])


def _checked_heading(truth: Channel) -> tuple[Channel, list[str]]:
    """The truth with a reversed heading corrected, and notes on what was found.

    A heading about 180 deg from the direction of motion gets pi added; one
    that drifts away from it or is otherwise inconsistent with it is kept,
    with a note.
    """
    check = heading_check(truth)
    found = (
        f"median {check['median_abs_diff_deg']:.1f} deg off, {100 * (check['share_over_90deg'] or 0.0):.1f} % "
        f"of {check['moving_samples']} moving samples over 90 deg"
    )
    if check["verdict"] == "reversed":
        note = f"truth heading (GT column 4) was 180 deg from the direction of motion ({found}); corrected (pi added)"
        return truth.replace(yaw_rad=truth.yaw_rad + np.pi), [note]
    if check["verdict"] == "drifting":
        return truth, [
            f"truth heading (GT column 4) drifts from the direction of motion by {check['drift_dps']:+.3f} deg/s "
            f"({check['drift_deg']:+.0f} deg over the drive; integrated from a biased gyro?); kept as recorded"
        ]
    if check["verdict"] == "inconsistent":
        return truth, [f"truth heading (GT column 4) disagrees with the direction of motion ({found}); kept as recorded"]
    return truth, []


def _true_ranges(t_s: np.ndarray, beacon_xy: np.ndarray, gt: np.ndarray) -> np.ndarray:
    east = np.interp(t_s, gt[:, 0], gt[:, 1])
    north = np.interp(t_s, gt[:, 0], gt[:, 2])
    true = np.hypot(east - beacon_xy[:, 0], north - beacon_xy[:, 1])
    true[(t_s < gt[0, 0]) | (t_s > gt[-1, 0])] = np.nan
    return true


def import_plaza(path: str | os.PathLike, origin: GeoOrigin = PLAZA_ORIGIN) -> Drive:
    """Read a CMU Plaza ``.mat`` file as a drive (conventions: module docstring).

    Parameters
    ----------
    path : path-like
        The ``.mat`` file (MATLAB v5/v7 format) with arrays GT, DR, TD, TL.
    origin : GeoOrigin
        Geodetic origin of the dataset's x/y frame, for map views.

    Raises
    ------
    FileFormatError
        Missing or unreadable file; an array missing, of the wrong shape or
        with times that do not increase.
    DriveError
        Values the drive model rejects (non-finite, implausible, a range to
        a beacon not in TL), naming the file, channel and row.
    """
    path = Path(path)
    arrays = _load(path)
    for name in ("GT", "DR", "TD", "TL"):
        # Every cell of a Plaza array is a value (a NaN range would pass as "no range" and fail later).
        bad = ~np.isfinite(arrays[name])
        if bad.any():
            row, col = (int(i) for i in np.argwhere(bad)[0])
            raise FileFormatError(f"{path}: array '{name}' row {row}, column {col}: {float(arrays[name][row, col])} is not a finite number")
    gt, dr, td, tl = arrays["GT"], arrays["DR"], arrays["TD"], arrays["TL"]
    order = np.argsort(td[:, 0], kind="stable")
    td = td[order]
    try:
        tags = TagMap(tl[:, 0], tl[:, 1], tl[:, 2], np.zeros(len(tl)), np.full(len(tl), -1))
        truth, notes = _checked_heading(_truth(gt, path))
        t_mid, speed, yaw_rate = _rates(dr, path)
        known = np.isin(td[:, 2], tags.tag_id)
        if not known.all():
            row = int(order[np.argmax(~known)])
            raise FileFormatError(f"{path}: array 'TD' row {row}: beacon {td[np.argmax(~known), 2]:g} is not in 'TL'")
        beacon_xy = tags.positions(td[:, 2].astype(np.int64))
        nan = np.full(len(td), np.nan)
        channels = {
            "imu": Channel("imu", {"t_s": t_mid, "accel_x_mps2": np.full(t_mid.size, np.nan), "accel_y_mps2": np.full(t_mid.size, np.nan), "yaw_rate_radps": yaw_rate}),
            "wheel": Channel("wheel", {"t_s": t_mid, "speed_mps": speed}),
            "rfid": Channel("rfid", {
                "t_s": td[:, 0],
                "tag_id": td[:, 2],
                "rss": nan,
                "range_m": td[:, 3],
                "true_range_m": _true_ranges(td[:, 0], beacon_xy, gt),
            }),
            "truth": truth,
        }
        params = {
            "source": "plaza",
            "file": path.name,
            "antenna_ids": sorted({float(a) for a in np.unique(td[:, 1]).tolist()}),
            "range_rows_reordered": int(np.count_nonzero(order != np.arange(order.size))),
            "true_range_m": "distance from GT (linearly interpolated at the reading time) to the beacon; truth, not a sensor",
        }
        if notes:
            params["import_notes"] = notes
        return Drive(name=path.stem, channels=channels, tags=tags, origin=origin, params=params)
    except DriveError as exc:
        # name the source array and its row (rfid rows were sorted by time)
        array = {"truth": "GT", "imu": "DR", "wheel": "DR", "rfid": "TD", "tags": "TL"}.get(exc.channel)
        if array is None or exc.row is None:
            raise exc.with_source(str(path)) from None
        row = int(order[exc.row]) if exc.channel == "rfid" else exc.row
        raise DriveError(exc.channel, exc.row, f"{exc.reason} (array '{array}' row {row})", str(path)) from None
