"""Posterior Cramer-Rao bounds on the position error (issue 18): :func:`position_bound`."""

from graphpos.bound.pcrb import Bound, bound_config, default_bound_range_model, position_bound

__all__ = ["Bound", "bound_config", "default_bound_range_model", "position_bound"]
