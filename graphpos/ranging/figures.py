"""song2016 Figures 6 and 7 on simulated calibration data (PNG, matplotlib Agg back-end).

Top row (Fig. 6): the averaged calibration RSS against distance with the
LSSVM and propagation-model curves, one panel per environment. Bottom row
(Fig. 7): the distance error of each model on the held-out 1 Hz readings
against their RSS (mean and STD per RSS bin).
"""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graphpos.io.outputs import atomic_output  # noqa: E402
from graphpos.ranging.calibration_data import simulate_collection  # noqa: E402
from graphpos.ranging.drive_models import calibrated_model  # noqa: E402
from graphpos.ranging.table1 import MODEL_KINDS  # noqa: E402
from graphpos.sim.rss import ENVIRONMENTS  # noqa: E402

_COLOURS = {"lssvm": "tab:blue", "propagation": "tab:orange"}


def plot_calibration(seed: int, path: str | os.PathLike) -> None:
    """Write the Fig. 6/7 panels for every environment to a PNG file."""
    envs = list(ENVIRONMENTS)
    fig, axes = plt.subplots(2, len(envs), figsize=(4.2 * len(envs), 7.5), squeeze=False)
    for col, environment in enumerate(envs):
        train = simulate_collection(environment, [seed, 0])
        held_out = simulate_collection(environment, [seed, 1])
        top, bottom = axes[0, col], axes[1, col]
        top.plot(train.distance_m, train.mean_rss, ".", color="0.4", label="averaged RSS (4 tags)")
        rss = held_out.readings.ravel()
        edges = np.arange(np.floor(rss.min() / 5) * 5, rss.max() + 5, 5)
        centre = 0.5 * (edges[:-1] + edges[1:])
        which = np.digitize(rss, edges) - 1
        for kind in MODEL_KINDS:
            model = calibrated_model(environment, kind, seed)
            grid = np.linspace(*model.input_range, 400)
            top.plot(model.predict_distance_m(grid), grid, color=_COLOURS[kind], label=kind)
            error = model.predict_distance_m(rss) - held_out.reading_distance_m
            counts = np.bincount(which, minlength=centre.size)[: centre.size]
            keep = counts >= 20
            mean = np.bincount(which, error, centre.size)[: centre.size][keep] / counts[keep]
            sq = np.bincount(which, error**2, centre.size)[: centre.size][keep] / counts[keep]
            std = np.sqrt(np.maximum(sq - mean**2, 0.0))
            bottom.errorbar(centre[keep], mean, yerr=std, color=_COLOURS[kind], capsize=2, label=kind)
        top.set(title=environment, xlabel="distance (m)", ylabel="RSS (0-255)")
        bottom.axhline(0.0, color="0.6", lw=0.8)
        bottom.set(xlabel="RSS (0-255)", ylabel="distance error (m), mean ± STD")
        top.legend(fontsize=8)
        bottom.legend(fontsize=8)
    fig.suptitle(f"RSS-distance fits (song2016 Fig. 6) and distance errors on held-out readings (Fig. 7), seed {seed}")
    fig.tight_layout()
    try:
        with atomic_output(path) as stream:
            fig.savefig(stream, format="png", dpi=110)
    finally:
        plt.close(fig)
