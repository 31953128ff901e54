"""GTSAM factor-graph estimators, by name (merged into :mod:`graphpos.registry`).

- ``graph-batch``: Levenberg–Marquardt over the whole drive with marginal
  covariances (``GraphConfig(range_scale="estimate")`` self-calibrates a
  common range scale);
- ``graph-isam2``: online iSAM2, causal output (``final=True``: smoothed);
- ``graph-fixed-lag``: incremental fixed-lag smoother for long drives, causal output;
- ``graph-fixed-lag-smoothed``: the same smoother's smoothed output, each
  keyframe as it leaves the window (``fixed_lag_s`` to ``fixed_lag_s`` + 1 s late);
- ``graph-ranges``: ranges only (RFID, RSU) with a constant-velocity prior,
  smoothed over the whole drive (:class:`~graphpos.graph.config.RangesConfig`).

The odometry graphs (:data:`ODOMETRY_ESTIMATORS`) take a
:class:`~graphpos.graph.config.GraphConfig`; the planar (Pose2)
or inertial (Pose3 + velocity + IMU bias) graph is chosen by
``parameterisation`` (``auto``: inertial when the drive has
accelerometers). :func:`~graphpos.graph.calibration.calibrate_range_scale`
turns a drive into a calibrated range model for the online estimators.
"""

from graphpos.estimator import Estimator
from graphpos.graph.estimators import GraphBatch, GraphFixedLag, GraphFixedLagSmoothed, GraphIsam2
from graphpos.graph.ranges import GraphRanges

#: The graphs built on odometry (wheel or IMU), which take a GraphConfig.
ODOMETRY_ESTIMATORS: tuple[str, ...] = (GraphBatch.name, GraphIsam2.name, GraphFixedLag.name, GraphFixedLagSmoothed.name)

ESTIMATORS: dict[str, type[Estimator]] = {
    GraphBatch.name: GraphBatch,
    GraphIsam2.name: GraphIsam2,
    GraphFixedLag.name: GraphFixedLag,
    GraphFixedLagSmoothed.name: GraphFixedLagSmoothed,
    GraphRanges.name: GraphRanges,
}
