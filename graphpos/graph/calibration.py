"""Range-scale self-calibration of the batch smoother.

A ranging radio may read long or short by a common factor (the Plaza UWB
ranges read about 6.9 % long: ``reading = scale * distance``). The scale is
estimated from the drive itself, without any truth, by profile likelihood:
for a trial scale ``s`` every range factor is built with ``reading / s`` and
sigma ``sigma / s`` — its whitened residual ``(reading - s d) / sigma`` stays
in reading units, so graph errors at different ``s`` are comparable — the
whole graph is solved by Levenberg–Marquardt (warm-started from the previous
trial), and a bounded Brent search over ``s`` minimises the solved error.

Why an outer loop and not a scale variable in the graph: the scale multiplies
every range, which no GTSAM built-in factor expresses; a Python CustomFactor
on every range of a whole-drive graph costs about 1.7 ms per call at 10k
variables (measured, GTSAM_NOTES.md), i.e. minutes per solve, whereas the
outer loop keeps all factors built-in and costs about a dozen warm solves.
"""

from __future__ import annotations

import gtsam
from scipy.optimize import minimize_scalar

from graphpos.graph.config import GraphConfig

#: Tolerance of the scale search (dimensionless).
SCALE_TOLERANCE = 2e-4


def estimate_range_scale(builder, initial: gtsam.Values, config: GraphConfig, what: str) -> tuple[float, gtsam.Values]:
    """Scale minimising the solved graph error, and the solution at that scale.

    Parameters
    ----------
    builder : GraphBuilder
        With its full history (range records and the other factors).
    initial : gtsam.Values
        Starting point of the first solve (the causal pass's estimate).
    """
    from graphpos.graph.estimators import optimise

    solved: dict[float, tuple[float, gtsam.Values]] = {}
    warm = [initial]

    def solved_error(scale: float) -> float:
        graph = builder.graph(scale)
        values = optimise(graph, warm[0], config, f"{what} (range scale {scale:.4f})")
        warm[0] = values
        err = graph.error(values)
        solved[scale] = (err, values)
        return err

    result = minimize_scalar(solved_error, bounds=config.range_scale_bounds, method="bounded", options={"xatol": SCALE_TOLERANCE})
    best = min(solved, key=lambda s: solved[s][0])
    builder.diagnostics["range_scale_solves"] = int(result.nfev)
    return float(best), solved[best][1]


def calibrate_range_scale(drive, config: GraphConfig | None = None, layout: str | None = None):
    """Self-calibrate a range-reporting radio on a drive, without its truth.

    Runs ``graph-batch`` with ``range_scale="estimate"`` and returns a
    :class:`~graphpos.ranging.model.LinearCalibration` with the estimated
    scale and, as its sigma, the robust spread (1.4826 x median absolute
    deviation) of the calibrated ranges about the smoothed trajectory. The
    online estimators then use it as their range model (calibrate once, run
    causally), e.g. ``GraphIsam2(range_model=calibrate_range_scale(drive))``.
    """
    import dataclasses

    import numpy as np

    from graphpos.graph.estimators import GraphBatch
    from graphpos.ranging.model import LinearCalibration

    config = dataclasses.replace(config or GraphConfig(), range_scale="estimate", output_covariance=False)
    est = GraphBatch(config, layout=layout, range_model=LinearCalibration())
    result = est.run(drive)
    builder = est.builder
    scale = builder.range_scale
    times = np.array([builder.keyframe_time(r.keyframe) for r in builder.range_records])
    reading = np.array([r.reading_m for r in builder.range_records])
    positions = np.column_stack([np.interp(times, result.t_s, result.east_m), np.interp(times, result.t_s, result.north_m)])
    marks = np.array([builder.landmark_positions[r.landmark_key] for r in builder.range_records])
    residual = reading / scale - np.linalg.norm(positions - marks, axis=1)
    sigma = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    return LinearCalibration(scale=scale, offset_m=0.0, sigma0_m=max(sigma, 0.05))
