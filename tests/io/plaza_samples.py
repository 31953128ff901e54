"""A small synthetic Plaza-layout .mat file with a known trajectory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io


def synthetic_plaza(path: Path, drop: str | None = None, **replace: np.ndarray) -> dict[str, np.ndarray]:
    """Write a Plaza-layout .mat: a robot on a 20 m circle at 1 m/s, 5 Hz
    odometry, ranges to 3 beacons 1.05 x long. ``drop`` leaves an array out,
    ``replace`` swaps arrays. Returns the arrays written."""
    t = 100.0 + np.arange(0, 60.0, 0.2)
    radius, speed = 20.0, 1.0
    phi = speed * (t - t[0]) / radius
    x, y = radius * np.cos(phi), radius * np.sin(phi)
    heading = np.mod(phi + np.pi / 2, 2 * np.pi)
    gt = np.column_stack([t, x, y, heading])
    chord = 2 * radius * np.sin(np.diff(phi) / 2)
    dheading = np.angle(np.exp(1j * np.diff(heading)))
    dr = np.column_stack([t[1:], chord, dheading])
    tl = np.array([[3.0, 0.0, 0.0], [7.0, 30.0, 0.0], [8.0, 0.0, -30.0]])
    t_td = t[::5] + 0.05
    beacon = np.tile([3.0, 7.0, 8.0], t_td.size)[: t_td.size]
    bx = tl[np.searchsorted(tl[:, 0], beacon), 1]
    by = tl[np.searchsorted(tl[:, 0], beacon), 2]
    true = np.hypot(np.interp(t_td, t, x) - bx, np.interp(t_td, t, y) - by)
    td = np.column_stack([t_td, np.full(t_td.size, 2.0), beacon, 1.05 * true])
    td[[3, 4]] = td[[4, 3]]  # out of time order, as in Plaza1
    arrays = {"GT": gt, "DR": dr, "DRp": gt.copy(), "TD": td, "TL": tl, **replace}
    if drop:
        arrays.pop(drop)
    scipy.io.savemat(path, arrays)
    return arrays


def turned_heading_copy(source: Path, path: Path, turn_rad: float = np.pi) -> dict[str, np.ndarray]:
    """Write a copy of the Plaza .mat ``source`` whose GT heading is turned by
    ``turn_rad`` (wrapped into [0, 2pi), as a recording would store it);
    every other array as it is. Returns the arrays written."""
    mat = scipy.io.loadmat(source)
    arrays = {k: v for k, v in mat.items() if not k.startswith("__")}
    gt = arrays["GT"].astype(np.float64).copy()
    gt[:, 3] = np.mod(gt[:, 3] + turn_rad, 2 * np.pi)
    arrays["GT"] = gt
    scipy.io.savemat(path, arrays)
    return arrays
