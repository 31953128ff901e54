"""How good a range model is on a drive with truth: range error by distance band."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphpos.drive import Drive
from graphpos.ranging.drive_models import true_ranges_m
from graphpos.ranging.model import RangeModel

#: Band edges (m) for RSS radios: song2016's reliable range is 6 m, its maximum 9 m.
RSS_BAND_EDGES_M = (0.0, 2.0, 4.0, 6.0, 9.0, np.inf)
#: Band edges (m) for radios reporting ranges (UWB, RSU two-way ranging).
RANGE_BAND_EDGES_M = (0.0, 10.0, 20.0, 30.0, 50.0, np.inf)


@dataclass(frozen=True)
class BandErrors:
    """Range error (predicted - true) of the readings whose true range is in [lo_m, hi_m).

    ``z_rms`` is the RMS of the error divided by the model's predicted
    1-sigma: near 1 when the sigma is honest, above 1 when overconfident.
    ``beyond_3_sigma`` is the fraction of readings off by more than three
    predicted sigmas (outliers, which range gating or robust losses must handle).
    """

    lo_m: float
    hi_m: float
    count: int
    mean_m: float
    std_m: float
    rms_m: float
    z_rms: float
    beyond_3_sigma: float


def range_errors(model: RangeModel, drive: Drive, edges_m: tuple[float, ...] | None = None) -> list[BandErrors]:
    """Range error of ``model`` on ``drive`` per true-distance band, then over all readings (last row).

    ``edges_m`` defaults to :data:`RSS_BAND_EDGES_M` for RSS models and
    :data:`RANGE_BAND_EDGES_M` otherwise. Bands without readings are left out.
    """
    if edges_m is None:
        edges_m = RSS_BAND_EDGES_M if model.input_column == "rss" else RANGE_BAND_EDGES_M
    true_m = true_ranges_m(drive)
    predicted_m, sigma_m = model.ranges(drive.rfid)
    ok = np.isfinite(true_m) & np.isfinite(predicted_m)
    bands = [(lo, hi) for lo, hi in zip(edges_m[:-1], edges_m[1:])] + [(edges_m[0], edges_m[-1])]
    rows = []
    for lo, hi in bands:
        sel = ok & (true_m >= lo) & (true_m < hi)
        if not sel.any():
            continue
        e = predicted_m[sel] - true_m[sel]
        z = e / sigma_m[sel]
        rows.append(BandErrors(lo, hi, int(sel.sum()), float(e.mean()), float(e.std()), float(np.sqrt(np.mean(e**2))),
                               float(np.sqrt(np.mean(z**2))), float(np.mean(np.abs(z) > 3))))
    return rows


def format_range_errors(rows: list[BandErrors]) -> str:
    """The rows as a text table (errors in metres)."""
    lines = [f"{'true range (m)':<16} {'readings':>8} {'mean':>7} {'STD':>7} {'RMS':>7} {'RMS/sigma':>9} {'>3 sigma':>9}"]
    for i, r in enumerate(rows):
        band = "all" if i == len(rows) - 1 else f"{r.lo_m:g}-{r.hi_m:g}"
        lines.append(f"{band:<16} {r.count:>8} {r.mean_m:7.2f} {r.std_m:7.2f} {r.rms_m:7.2f} {r.z_rms:9.2f} {r.beyond_3_sigma:9.1%}")
    return "\n".join(lines)
