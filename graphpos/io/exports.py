"""Trajectory exports of an :class:`~graphpos.estimate.Estimate`.

- TUM (``t x y z qx qy qz qw``, space separated) for `evo
  <https://github.com/MichaelGrupp/evo>`_: east, north, 0 and the yaw as a
  rotation about the up axis (identity where the estimator gives no yaw).
- KML for Google Earth and GeoJSON for map viewers (Foxglove's Map panel,
  geojson.io): the track in WGS84 longitude/latitude, from the drive's
  :class:`~graphpos.drive.GeoOrigin` (:func:`graphpos.io.geo.enu_to_geodetic`).
- CSV with :data:`graphpos.estimate.CSV_COLUMNS`.

Every track is drawn in its estimator's colour (:mod:`graphpos.colors`):
the KML line style, the GeoJSON ``stroke`` property (simplestyle, which
geojson.io draws).

:func:`write_exports` writes all of them, the MCAP file for Foxglove and the
ROS 2 bag into one folder: the exports of ``graphpos run`` and of each drive
of ``graphpos evaluate``.

Every file is written atomically (temporary file in the same folder, then
rename), so a crash never leaves a truncated export that looks whole.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from graphpos.colors import color_of, kml_color_of
from graphpos.drive import Drive, GeoOrigin
from graphpos.estimate import CSV_COLUMNS, Estimate
from graphpos.io.geo import enu_to_geodetic
from graphpos.io.mcap_drive import float_texts, write_drive
from graphpos.io.outputs import atomic_output, safe_name
from graphpos.io.ros2_bag import write_odometry_bag

#: The drive with every estimate, for Foxglove (:func:`graphpos.io.write_drive`).
MCAP_FILE = "estimates.mcap"
#: The ROS 2 bag folder of the estimates (:func:`graphpos.io.ros2_bag.write_odometry_bag`).
ROS2_BAG = "estimates_ros2"
#: Every track in one Google Earth file.
ALL_TRACKS_KML = "all_estimates.kml"
#: The name (and file stem) of the truth among the exports.
TRUTH = "truth"

def write_atomically(path: str | os.PathLike, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` (folders created) through :func:`graphpos.io.outputs.atomic_output`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as stream:
        stream.write(data.encode() if isinstance(data, str) else data)
    return path


def tum_text(estimate: Estimate) -> str:
    """The estimate in TUM trajectory format (one pose per line)."""
    yaw = estimate.yaw_rad if estimate.yaw_rad is not None else np.zeros(len(estimate))
    qz, qw = np.sin(yaw / 2), np.cos(yaw / 2)
    lines = [
        f"{t:.6f} {e:.4f} {n:.4f} 0 0 0 {z:.9f} {w:.9f}"
        for t, e, n, z, w in zip(estimate.t_s, estimate.east_m, estimate.north_m, qz, qw)
    ]
    return "\n".join(lines) + ("\n" if lines else "")


def geojson_dict(estimate: Estimate, origin: GeoOrigin) -> dict:
    """A GeoJSON FeatureCollection with the track as one LineString."""
    lat, lon = enu_to_geodetic(estimate.east_m, estimate.north_m, origin)
    coords = [[round(float(a), 9), round(float(b), 9)] for a, b in zip(lon, lat)]
    feature = {
        "type": "Feature",
        "properties": {
            "name": estimate.name,
            "stroke": color_of(estimate.name),
            "start_s": float(estimate.t_s[0]) if len(estimate) else None,
            "end_s": float(estimate.t_s[-1]) if len(estimate) else None,
        },
        "geometry": {"type": "LineString", "coordinates": coords},
    }
    return {"type": "FeatureCollection", "features": [feature]}


def kml_text(estimates: list[Estimate], origin: GeoOrigin) -> str:
    """KML with one track per estimate, each in its estimator's colour."""
    import simplekml

    kml = simplekml.Kml()
    for est in estimates:
        lat, lon = enu_to_geodetic(est.east_m, est.north_m, origin)
        line = kml.newlinestring(name=est.name, coords=list(zip(lon.tolist(), lat.tolist())))
        line.style.linestyle.width = 3
        line.style.linestyle.color = kml_color_of(est.name)
    return kml.kml()


def csv_text(estimate: Estimate) -> str:
    """The estimate as CSV with :data:`CSV_COLUMNS` (empty cells where not
    estimated or not finite), each value in Python's shortest round-trip repr."""
    table = estimate.table()
    cells = [float_texts(table[c], nan=b"", inf=b"", minus_inf=b"") for c in CSV_COLUMNS]
    return b"\n".join([",".join(CSV_COLUMNS).encode(), *map(b",".join, zip(*cells)), b""]).decode()


def export_estimate(estimate: Estimate, origin: GeoOrigin, folder: str | os.PathLike, stem: str | None = None) -> dict[str, Path]:
    """Write ``<stem>.tum``, ``.kml``, ``.geojson`` and ``.csv`` into ``folder``; returns the paths by format."""
    folder = Path(folder)
    stem = stem or estimate.name
    return {
        "tum": write_atomically(folder / f"{stem}.tum", tum_text(estimate)),
        "kml": write_atomically(folder / f"{stem}.kml", kml_text([estimate], origin)),
        "geojson": write_atomically(folder / f"{stem}.geojson", json.dumps(geojson_dict(estimate, origin))),
        "csv": write_atomically(folder / f"{stem}.csv", csv_text(estimate)),
    }


def truth_estimate(drive: Drive) -> Estimate:
    """The drive's truth as an :class:`Estimate` named :data:`TRUTH`, at the truth's own rate."""
    tr = drive.truth
    return Estimate(TRUTH, tr.t_s, tr.east_m, tr.north_m, tr.v_east_mps, tr.v_north_mps, tr.yaw_rad)


def write_exports(folder: str | os.PathLike, drive: Drive, estimates: list[Estimate], bags: bool = True) -> None:
    """Every export of estimates of one drive into ``folder`` (created): what ``run`` writes, and
    ``evaluate`` for each drive.

    - ``<name>.csv`` for each estimate (only the header when it has no
      output: the estimator never started), and ``<name>.tum``, ``.kml``,
      ``.geojson`` for each estimate with an output (:func:`export_estimate`);
    - ``truth.csv``, ``.tum``, ``.kml``, ``.geojson``: the same of the
      drive's truth at its own rate, when the drive has truth
      (``evo_ape tum truth.tum graph-batch.tum``);
    - :data:`ALL_TRACKS_KML`: every track, the truth's among them, in one
      Google Earth file;
    - with ``bags``: :data:`MCAP_FILE`, the drive and every estimate (open it
      in Foxglove), and :data:`ROS2_BAG`, a ROS 2 bag with each estimate
      and the truth as ``nav_msgs/Odometry`` (:mod:`graphpos.io.ros2_bag`).

    ``<name>`` is the estimate's name made file-safe
    (:func:`graphpos.io.outputs.safe_name`).

    Parameters
    ----------
    folder : path-like
        Inside an output folder (:func:`graphpos.io.outputs.output_folder`);
        the ROS 2 bag folder must not exist yet.
    drive : Drive
        The drive the estimates are of (with its truth, when it has one).
    estimates : list of Estimate
        Unique names, none of them :data:`TRUTH`.
    bags : bool
        Whether to write the MCAP file and the ROS 2 bag.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    everything = ([truth_estimate(drive)] if drive.has("truth") else []) + list(estimates)
    for est in everything:
        stem = safe_name(est.name)
        if len(est):
            export_estimate(est, drive.origin, folder, stem)
        else:
            write_atomically(folder / f"{stem}.csv", csv_text(est))
    tracks = [e for e in everything if len(e)]
    if tracks:
        write_atomically(folder / ALL_TRACKS_KML, kml_text(tracks, drive.origin))
    if bags:
        write_drive(folder / MCAP_FILE, drive, estimates=estimates)
        write_odometry_bag(folder / ROS2_BAG, everything)
