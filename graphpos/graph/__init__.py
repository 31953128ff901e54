"""GTSAM factor-graph estimators, by name (merged into :mod:`graphpos.registry`)."""

from graphpos.estimator import Estimator
from graphpos.graph.estimators import GraphBatch, GraphFixedLag, GraphIsam2

ESTIMATORS: dict[str, type[Estimator]] = {
    GraphBatch.name: GraphBatch,
    GraphIsam2.name: GraphIsam2,
    GraphFixedLag.name: GraphFixedLag,
}
