"""Searching tag layouts by the position bound (issue 18, item 3).

The bound (:func:`graphpos.bound.position_bound`) is a lower limit on the
position error of every estimator using the same sensors: a layout whose
bound misses the target cannot meet it, whichever estimator runs. So for
each family the search finds, by bisection over the family's spacings (the
bound grows as the tags thin out), the layout with the fewest tags whose
bound still meets the target: the family's *frontier*. Every cheaper
layout of that family is ruled out without a simulation. Each bound costs
one simulated drive (seed 0) and one bound computation, about a second;
evaluations are cached, so a second search (another target) is cheaper.

With a tag budget instead of a target, each family's densest layout within
the budget is evaluated and the families are ranked by their bound.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np

from graphpos.bound import position_bound
from graphpos.errors import ConfigError, GraphposError
from graphpos.plan.tunnel import BASE_SCENARIO, Candidate, TunnelSpec, family_grid
from graphpos.sim.infrastructure import FAMILIES

#: The window a plan is scored in.
WINDOW = "in_tunnel"
#: Target metrics: RMS over the tunnel of sqrt(trace), or its largest value.
METRICS = ("rms", "max")


@dataclass
class BoundEvaluation:
    """The bound of one layout on the plan's drive.

    Attributes
    ----------
    candidate : Candidate
    n_tags : int
    value_m : float
        The target metric of the bound in the tunnel (NaN when it failed; see ``error``).
    distance_m, sqrt_trace_m : arrays
        The bound along the tunnel: distance from the entry portal and sqrt(trace) at each keyframe inside.
    seconds : float
    error : str or None
    """

    candidate: Candidate
    n_tags: int
    value_m: float
    distance_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sqrt_trace_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: float = 0.0
    error: str | None = None


class BoundSearch:
    """Bound evaluations of a tunnel's candidate layouts, cached.

    Parameters
    ----------
    spec : TunnelSpec
    kind : str
        ``smoother`` or ``filtering``: the bound of the estimator the target is for.
    metric : str
        ``rms`` or ``max`` (see :data:`METRICS`).
    progress : callable, optional
        Called with a line per evaluation.
    """

    def __init__(self, spec: TunnelSpec, kind: str = "smoother", metric: str = "rms",
                 progress: Callable[[str], None] | None = None) -> None:
        if kind not in ("smoother", "filtering"):
            raise ConfigError(f"unknown bound kind '{kind}' (smoother or filtering)")
        if metric not in METRICS:
            raise ConfigError(f"unknown target metric '{metric}' (known: {', '.join(METRICS)})")
        self.spec, self.kind, self.metric, self.progress = spec, kind, metric, progress
        self.cache: dict[Candidate, BoundEvaluation] = {}

    def evaluate(self, candidate: Candidate) -> BoundEvaluation:
        """The bound of one layout (cached)."""
        if candidate in self.cache:
            return self.cache[candidate]
        from graphpos.sim import simulate

        started = time.perf_counter()
        n = candidate.n_tags(self.spec)
        try:
            drive = simulate(BASE_SCENARIO, pattern=self.spec.pattern, seed=0,
                             overrides={**self.spec.overrides(), "tags": candidate.tags()})
            bound = position_bound(drive, filtering=self.kind == "filtering")
            inside = bound.mask(WINDOW)
            root = bound.sqrt_trace(self.kind)[inside]
            entry = min(w.start_s for w in drive.windows if w.label == WINDOW)
            distance = (bound.t_s[inside] - entry) * self.spec.speed_mps
            finite = root[np.isfinite(root)]
            value = float(np.sqrt(np.mean(finite ** 2)) if self.metric == "rms" else np.max(finite)) if finite.size else math.nan
            ev = BoundEvaluation(candidate, n, value, distance, root, time.perf_counter() - started)
        except GraphposError as exc:
            ev = BoundEvaluation(candidate, n, math.nan, seconds=time.perf_counter() - started, error=str(exc))
        self.cache[candidate] = ev
        if self.progress is not None:
            self.progress(_line(ev))
        return ev

    def frontier(self, family: str, target_m: float) -> BoundEvaluation | None:
        """The family's layout with the fewest tags whose bound meets ``target_m`` (None: not even the densest).

        Bisection over :func:`graphpos.plan.tunnel.family_grid` (most tags
        first), on the assumption that thinning a family's tags never
        lowers its bound.
        """
        grid = family_grid(self.spec, family)

        def meets(i: int) -> bool:
            v = self.evaluate(grid[i]).value_m
            return math.isfinite(v) and v <= target_m

        if not grid or not meets(0):
            return None
        lo, hi = 0, len(grid) - 1  # lo meets; find the last index that meets
        if meets(hi):
            return self.cache[grid[hi]]
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if meets(mid):
                lo = mid
            else:
                hi = mid
        return self.cache[grid[lo]]

    def frontiers(self, target_m: float, families: tuple[str, ...] = FAMILIES, pool: Executor | None = None
                  ) -> dict[str, BoundEvaluation | None]:
        """:meth:`frontier` of every family; with ``pool`` (a process pool) the families in parallel."""
        if pool is None:
            return {f: self.frontier(f, target_m) for f in families}
        futures = {f: pool.submit(_family_frontier, self.spec, self.kind, self.metric, f, target_m) for f in families}
        out: dict[str, BoundEvaluation | None] = {}
        for f, fut in futures.items():
            found, evaluations = fut.result()
            for ev in evaluations:
                if ev.candidate not in self.cache and self.progress is not None:
                    self.progress(_line(ev))
                self.cache.setdefault(ev.candidate, ev)
            out[f] = found
        return out

    def within_budget(self, budget: int, families: tuple[str, ...] = FAMILIES) -> dict[str, BoundEvaluation | None]:
        """Each family's layout with the most tags not over ``budget`` (None: even its sparsest is over)."""
        out: dict[str, BoundEvaluation | None] = {}
        for f in families:
            fitting = [c for c in family_grid(self.spec, f) if c.n_tags(self.spec) <= budget]
            out[f] = self.evaluate(fitting[0]) if fitting else None
        return out

    def cheaper(self, than: Candidate) -> list[BoundEvaluation]:
        """Evaluated layouts with fewer tags than ``than``, nearest in tag count first."""
        n = than.n_tags(self.spec)
        rows = [e for e in self.cache.values() if e.n_tags < n]
        return sorted(rows, key=lambda e: (n - e.n_tags, e.value_m if math.isfinite(e.value_m) else math.inf))


def _line(ev: BoundEvaluation) -> str:
    shown = f"{ev.value_m:.3f} m" if math.isfinite(ev.value_m) else f"failed ({ev.error})"
    return f"bound of {ev.candidate.label} ({ev.n_tags} tags): {shown}"


def _family_frontier(spec: TunnelSpec, kind: str, metric: str, family: str, target_m: float
                     ) -> tuple[BoundEvaluation | None, list[BoundEvaluation]]:
    """One family's frontier and every evaluation it took (for a pool worker)."""
    search = BoundSearch(spec, kind, metric)
    return search.frontier(family, target_m), list(search.cache.values())
