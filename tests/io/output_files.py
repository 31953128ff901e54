"""What a folder of exports holds (:func:`graphpos.io.exports.write_exports`), for the tests that list an
output folder of ``run`` or ``evaluate``."""

from __future__ import annotations


def export_files(names: list[str], truth: bool = True, bags: bool = True) -> set[str]:
    """The top-level names of the exports of the estimates ``names`` (each with at least one output) and,
    with ``truth``, of the drive's truth; with ``bags``, the MCAP file and the ROS 2 bag folder."""
    stems = [*names, *(["truth"] if truth else [])]
    files = {f"{stem}.{ext}" for stem in stems for ext in ("csv", "tum", "kml", "geojson")} | {"all_estimates.kml"}
    return files | ({"estimates.mcap", "estimates_ros2"} if bags else set())
