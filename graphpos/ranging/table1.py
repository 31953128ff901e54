"""song2016 Table 1: mean and STD of the "RSS fitting errors", LSSVM against the propagation model.

Our reading (the paper does not define the error): the error of the fitted
RSS-distance relationship *as a distance estimate*, i.e. predicted minus
true distance, in metres. The LSSVM's output is distance (song2016 §3), the
paper's Figure 7 plots "distance estimation errors" against RSS beside
Table 1, and distance is what the filters consume. Both models are scored
the same way: each model maps every reading to a distance (the LSSVM by
eq. 9, the propagation model by its inverted log-distance law).

The paper's magnitudes (STD 3-10) look like RSS units rather than metres
over a 9 m range, so the RSS-space error is reported beside: a reading's
RSS minus the RSS the fitted curve gives at the true distance (0-255
units; the curve is read off each model's own RSS -> distance function and
inverted, so again both models are scored alike). The unit-free figure the
two readings share is the ratio of the two models' STDs (LSSVM over
propagation), printed for ours in both units beside the paper's. In RSS
units the two models stay closer than in distance: per-reading fading,
which neither model can remove, is a large part of the RSS error, while in
distance the propagation model's misfit of the law's structure (ground or
wall interference, the near-range flattening, the sensitivity floor; see
:mod:`graphpos.sim.rss`) is magnified where the curve is flat, far out.

Errors are measured on held-out data: the individual 1 Hz readings of a
second collection with four other tags (the models are fitted on the
averaged first collection, as in song2016 §6.1). On the training averages a
least-squares fit has zero-mean residuals by construction; the paper's means
are not zero.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from graphpos.ranging.calibration_data import simulate_collection
from graphpos.ranging.drive_models import CALIBRATION_SEED, calibrated_model
from graphpos.ranging.rss_model import RssRangeModel
from graphpos.sim.rss import ENVIRONMENTS

#: song2016 Table 1 (mean, STD) per environment and model.
PUBLISHED_TABLE1: dict[str, dict[str, tuple[float, float]]] = {
    "laboratory": {"lssvm": (0.97, 4.07), "propagation": (1.81, 8.19)},
    "outdoor": {"lssvm": (0.75, 3.13), "propagation": (-1.55, 8.28)},
    "tunnel": {"lssvm": (1.17, 5.52), "propagation": (2.37, 10.43)},
}

MODEL_KINDS = ("lssvm", "propagation")


def curve_rss(model: RssRangeModel, distance_m: np.ndarray, grid_points: int = 4096) -> np.ndarray:
    """RSS the model's fitted curve gives at each distance.

    The model's distance function is evaluated on a fine grid over its
    training RSS range; its monotone envelope (distance non-increasing as RSS
    grows) is inverted by linear interpolation. Distances beyond the curve's
    ends get the end RSS.
    """
    rss_grid = np.linspace(*model.input_range, grid_points)
    d_grid = model.predict_distance_m(rss_grid)
    # walking from strong to weak RSS, distance may only grow
    d_increasing = np.maximum.accumulate(d_grid[::-1])
    return np.interp(distance_m, d_increasing, rss_grid[::-1])


def fitting_errors(environment: str, seed: int = CALIBRATION_SEED) -> dict[str, dict[str, float]]:
    """Table 1 figures of one environment for both models.

    Returns
    -------
    dict
        ``{kind: {mean, std, rms, rss_mean, rss_std}}``: ``mean``/``std``/``rms``
        of the distance error (m), ``rss_*`` of the RSS error (0-255 units),
        on held-out readings.
    """
    held_out = simulate_collection(environment, [seed, 1])
    rss = held_out.readings.ravel()
    true_m = held_out.reading_distance_m
    result = {}
    for kind in MODEL_KINDS:
        model = calibrated_model(environment, kind, seed)
        rss_error = rss - curve_rss(model, true_m)
        distance_error = model.predict_distance_m(rss) - true_m
        result[kind] = {
            "mean": float(np.mean(distance_error)),
            "std": float(np.std(distance_error)),
            "rms": float(np.sqrt(np.mean(distance_error**2))),
            "rss_mean": float(np.mean(rss_error)),
            "rss_std": float(np.std(rss_error)),
        }
    return result


def table1(seed: int = CALIBRATION_SEED) -> dict[str, dict[str, dict[str, float]]]:
    """:func:`fitting_errors` for every environment of :data:`graphpos.sim.rss.ENVIRONMENTS`."""
    return {environment: fitting_errors(environment, seed) for environment in ENVIRONMENTS}


def std_ratio(row: dict[str, dict[str, float]], key: str = "std") -> float:
    """LSSVM's STD over the propagation model's (``key``: ``std`` in metres, ``rss_std`` in RSS units)."""
    return float(row["lssvm"][key] / row["propagation"][key])


def published_std_ratio(environment: str) -> float:
    """song2016 Table 1's LSSVM STD over its propagation-model STD."""
    paper = PUBLISHED_TABLE1[environment]
    return paper["lssvm"][1] / paper["propagation"][1]


def format_table1(figures: dict[str, dict[str, dict[str, Any]]], seed: int) -> str:
    """The table as text, ours beside the paper's."""
    lines = [
        f"song2016 Table 1, simulated (seed {seed}): distance error (m) of each model on held-out 1 Hz",
        "readings of four other tags, beside the paper's figures (units unstated, likely RSS 0-255);",
        "the RSS-space error (0-255 units) at right",
        "",
        f"{'environment':<12} {'model':<12} {'mean':>7} {'STD':>7} {'RMS':>7} {'paper mean':>11} {'paper STD':>10}"
        f" {'RSS mean':>9} {'RSS STD':>8}",
    ]
    for environment, row in figures.items():
        for kind in MODEL_KINDS:
            ours = row[kind]
            paper = PUBLISHED_TABLE1.get(environment, {}).get(kind, (np.nan, np.nan))
            lines.append(
                f"{environment:<12} {kind:<12} {ours['mean']:7.2f} {ours['std']:7.2f} {ours['rms']:7.2f}"
                f" {paper[0]:11.2f} {paper[1]:10.2f} {ours['rss_mean']:9.2f} {ours['rss_std']:8.2f}"
            )
    lines += ["", "STD ratio, LSSVM / propagation model:",
              f"{'environment':<12} {'ours (m)':>9} {'ours (RSS)':>11} {'paper':>7}"]
    for environment, row in figures.items():
        paper_ratio = published_std_ratio(environment) if environment in PUBLISHED_TABLE1 else np.nan
        lines.append(f"{environment:<12} {std_ratio(row):9.2f} {std_ratio(row, 'rss_std'):11.2f} {paper_ratio:7.2f}")
    return "\n".join(lines)
