"""The papers' Kalman-filter estimators, by name.

Each paper module defines ``ESTIMATORS`` (name -> Estimator class); they are
merged here for :mod:`graphpos.registry`.
"""

from graphpos.estimator import Estimator

ESTIMATORS: dict[str, type[Estimator]] = {}
