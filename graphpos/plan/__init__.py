"""Planning tag layouts by the position bound (``graphpos plan-layout``, issue 18)."""

from graphpos.plan.search import METRICS, BoundEvaluation, BoundSearch
from graphpos.plan.tunnel import BASE_SCENARIO, PATTERN, Candidate, TunnelSpec, family_grid

__all__ = ["BASE_SCENARIO", "METRICS", "PATTERN", "BoundEvaluation", "BoundSearch", "Candidate", "TunnelSpec", "family_grid"]
