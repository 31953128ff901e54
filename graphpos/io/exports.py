"""Trajectory exports of an :class:`~graphpos.estimate.Estimate`.

- TUM (``t x y z qx qy qz qw``, space separated) for `evo
  <https://github.com/MichaelGrupp/evo>`_: east, north, 0 and the yaw as a
  rotation about the up axis (identity where the estimator gives no yaw).
- KML for Google Earth and GeoJSON for map viewers (Foxglove's Map panel,
  geojson.io): the track in WGS84 longitude/latitude, from the drive's
  :class:`~graphpos.drive.GeoOrigin` (:func:`graphpos.io.geo.enu_to_geodetic`).
- CSV with :data:`graphpos.estimate.CSV_COLUMNS`.

Every file is written atomically (temporary file in the same folder, then
rename), so a crash never leaves a truncated export that looks whole.
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

import numpy as np

from graphpos.drive import GeoOrigin
from graphpos.io.outputs import atomic_output
from graphpos.io.geo import enu_to_geodetic
from graphpos.estimate import CSV_COLUMNS, Estimate

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
            "start_s": float(estimate.t_s[0]) if len(estimate) else None,
            "end_s": float(estimate.t_s[-1]) if len(estimate) else None,
        },
        "geometry": {"type": "LineString", "coordinates": coords},
    }
    return {"type": "FeatureCollection", "features": [feature]}


def kml_text(estimates: list[Estimate], origin: GeoOrigin, colors: dict[str, str] | None = None) -> str:
    """KML with one track per estimate (``colors``: name -> ``aabbggrr`` KML colour)."""
    import simplekml

    kml = simplekml.Kml()
    for est in estimates:
        lat, lon = enu_to_geodetic(est.east_m, est.north_m, origin)
        line = kml.newlinestring(name=est.name, coords=list(zip(lon.tolist(), lat.tolist())))
        line.style.linestyle.width = 3
        if colors and est.name in colors:
            line.style.linestyle.color = colors[est.name]
    return kml.kml()


def csv_text(estimate: Estimate) -> str:
    """The estimate as CSV with :data:`CSV_COLUMNS` (empty cells where not estimated)."""
    table = estimate.table()
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    cols = [table[c] for c in CSV_COLUMNS]
    for row in zip(*cols):
        writer.writerow(["" if not np.isfinite(v) else repr(float(v)) for v in row])
    return buf.getvalue()


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
