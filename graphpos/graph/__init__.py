"""GTSAM factor-graph estimators, by name (merged into :mod:`graphpos.registry`)."""

from graphpos.estimator import Estimator

ESTIMATORS: dict[str, type[Estimator]] = {}
