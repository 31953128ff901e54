"""Files in and out: drives and estimates in MCAP, dataset importers.

- :func:`write_drive` / :func:`read_drive` / :func:`read_estimates` /
  :func:`read_mcap` (both at once): one drive
  (and optionally estimates) per MCAP file, lossless, viewable in Foxglove
  (:mod:`graphpos.io.mcap_drive` documents the layout).
- :func:`graphpos.io.plaza.import_plaza`: the CMU Plaza ranging datasets.
- :func:`graphpos.io.rosbag.import_rosbag`, :func:`graphpos.io.csvlog.import_csv`:
  ROS bags and CSV logs through a mapping file (:mod:`graphpos.io.mapping`).
- :func:`graphpos.io.geo.enu_to_geodetic` / ``geodetic_to_enu``: local east/north <-> lat/lon (WGS84, pymap3d).
- :func:`graphpos.io.exports.write_exports`: the exports of ``run`` and
  ``evaluate`` (TUM, KML, GeoJSON, CSV, the MCAP file, and the ROS 2 bag of
  :mod:`graphpos.io.ros2_bag`).
"""

import importlib

__all__ = ["read_drive", "read_estimates", "read_mcap", "write_drive"]


def __getattr__(name: str):
    """The public names, from :mod:`graphpos.io.mcap_drive` on first use (PEP 562), so that importing a
    light sub-module (``graphpos.io.files``) does not import numpy, msgspec and mcap."""
    if name not in __all__:
        raise AttributeError(f"module 'graphpos.io' has no attribute {name!r}")
    value = getattr(importlib.import_module("graphpos.io.mcap_drive"), name)
    globals()[name] = value
    return value
