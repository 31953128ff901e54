"""One colour per estimator name, the same in every plot, KML track and Foxglove map.

:data:`ESTIMATOR_COLORS` gives each registered estimator its colour
(matplotlib's ``tab20`` colours, the strong ones to the estimators the
reports compare most, and two of ``tab20b`` for the graph variants added
later); the truth is black. A name not in the table (an
estimator added later, a test's) takes a colour of :data:`SPARE_COLORS`
chosen by a checksum of its name, so that it too keeps its colour from one
run to the next. The plots (:mod:`eval.plots`), the KML exports
(:mod:`graphpos.io.exports`) and the ``foxglove.LocationFix`` messages of the
MCAP files (:mod:`graphpos.io.mcap_drive`) all read :func:`color_of`.
"""

from __future__ import annotations

import zlib

#: The truth's colour.
TRUTH_COLOR = "#000000"
#: Colour of each estimator (``#rrggbb``), and of the truth.
ESTIMATOR_COLORS: dict[str, str] = {
    "truth": TRUTH_COLOR,
    "fusion-ekf": "#1f77b4",
    "fukf": "#ff7f0e",
    "graph-isam2": "#2ca02c",
    "graph-batch": "#d62728",
    "graph-fixed-lag": "#9467bd",
    "graph-fixed-lag-smoothed": "#7b4173",
    "graph-ranges": "#637939",
    "two-level-ekf": "#8c564b",
    "rfid-ekf": "#e377c2",
    "multilateration": "#7f7f7f",
    "dr": "#bcbd22",
    "lms-federated": "#17becf",
    "ekf-ca": "#aec7e8",
    "stekf-ca": "#ffbb78",
    "imm-stekf": "#98df8a",
    "fkf": "#ff9896",
}
#: Colours of names not in :data:`ESTIMATOR_COLORS` (the rest of ``tab20``).
SPARE_COLORS = ("#c5b0d5", "#c49c94", "#f7b6d2", "#dbdb8d", "#9edae5")


def color_of(name: str) -> str:
    """The ``#rrggbb`` colour of an estimator (or ``truth``)."""
    if name in ESTIMATOR_COLORS:
        return ESTIMATOR_COLORS[name]
    return SPARE_COLORS[zlib.crc32(name.encode("utf-8", "surrogatepass")) % len(SPARE_COLORS)]


def rgb_of(name: str) -> tuple[float, float, float]:
    """:func:`color_of` as red, green and blue in [0, 1] (Foxglove's ``foxglove.Color``)."""
    text = color_of(name)
    return tuple(int(text[i : i + 2], 16) / 255 for i in (1, 3, 5))


def kml_color_of(name: str) -> str:
    """:func:`color_of` as KML writes it: ``aabbggrr``, opaque."""
    text = color_of(name)
    return f"ff{text[5:7]}{text[3:5]}{text[1:3]}"
