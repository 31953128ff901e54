"""``graphpos plan-layout``: the cheapest tag layout whose error meets a target (issue 18, item 3).

Two stages:

1. **By the bound** (:class:`graphpos.plan.BoundSearch`, seconds): for every
   layout family the frontier, the fewest tags whose position bound meets
   the target. The bound is a lower limit for any estimator on these
   sensors, so a cheaper layout of the family is ruled out outright.
2. **By simulation** (the runs of ``layout-study``: the same drives, seeds
   0..N-1, the estimator scored in the tunnel): the bound-feasible layouts,
   cheapest first (one per tag count), are bisected by their mean simulated
   error to the cheapest that meets the target. The choice is then
   confirmed on fresh seeds (100, 101, ...): there the one-sided 90 % upper
   confidence limit of the mean must meet the target (a sparse layout's
   error varies a lot between drives; its mean over two can meet a target
   its mean over ten misses); if it does not, the next denser layout that
   meets on the search's seeds is confirmed in turn (bisected for on the
   search's seeds, whose runs are mostly done: one fresh confirmation per
   layout tried, not one per bisection step). Its two nearest cheaper rivals are simulated
   too, and a rival that also passes takes the choice over, until both
   rivals of the chosen layout fail. Chosen layout and rivals are reported
   with both figures.

A simulated error near the bound means the estimator is efficient there;
far above it, the estimator (or the bound's white-noise model of the
sensors: compass disturbances and biases are not white) leaves accuracy
on the table, which is why the choice is confirmed by simulation.

With ``budget`` (a tag count) instead of a target: each family's densest
layout within the budget, ranked by the bound; the best three simulated.

Output folder: ``report.md``/``.html``, ``results.json``, ``plan.png`` (the
bound along the tunnel and the chosen tags) and ``layout.toml`` (the
chosen layout's simulator parameters: ``graphpos simulate
paper-comprehensive --pattern constant --config layout.toml``).
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eval import plots
from eval.bounds import bound_kind
from eval.execution import Job, SimSource, execute, executor, provenance
from eval.reproduce import window_stat
from eval.report import Report, fmt, write_json
from graphpos.errors import ConfigError
from graphpos.io.exports import write_atomically
from graphpos.io.outputs import output_folder
from graphpos.plan import BASE_SCENARIO, BoundEvaluation, BoundSearch, Candidate, TunnelSpec, family_grid
from graphpos.plan.search import WINDOW
from graphpos.sim.params import sensor_set

#: First of the fresh seeds the chosen layout is confirmed on (the search uses seeds 0, 1, ...).
FRESH_SEED = 100



@dataclass
class Simulated:
    """One layout's simulated error: the estimator's tunnel metric per seed."""

    candidate: Candidate
    per_seed_m: list[float]
    errors: list[str] = field(default_factory=list)

    @property
    def value_m(self) -> float:
        ok = [v for v in self.per_seed_m if math.isfinite(v)]
        return float(np.mean(ok)) if ok and not self.errors else math.nan

    @property
    def upper_m(self) -> float:
        """One-sided 90 % upper confidence limit of the mean over seeds (Student t; NaN for one seed, which
        gives no limit): a sparse layout's error varies a lot from drive to drive, and its mean over a few
        drives can meet a target its mean over many misses."""
        from scipy.stats import t as student_t

        n = len(self.per_seed_m)
        if n < 2 or not math.isfinite(self.value_m):
            return math.nan
        return self.value_m + float(student_t.ppf(0.9, n - 1)) * float(np.std(self.per_seed_m, ddof=1)) / math.sqrt(n)


@dataclass
class PlanOutcome:
    """What ``plan-layout`` found."""

    folder: Path
    chosen: Candidate | None
    met: bool


class _Simulator:
    """Simulated errors of layouts (cached): the estimator on the drives of ``seeds``, as layout-study runs it."""

    def __init__(self, spec: TunnelSpec, estimator: str, seeds: range, metric: str, pool, say) -> None:
        self.spec, self.estimator, self.seeds, self.metric, self.pool, self.say = spec, estimator, seeds, metric, pool, say
        self.cache: dict[Candidate, Simulated] = {}

    def source(self, c: Candidate, seed: int) -> SimSource:
        return SimSource(BASE_SCENARIO, self.spec.pattern, seed, overrides_json=json.dumps({**self.spec.overrides(), "tags": c.tags()}))

    def run(self, candidates: list[Candidate]) -> list[Simulated]:
        todo = [c for c in dict.fromkeys(candidates) if c not in self.cache]
        jobs = [Job(self.source(c, s), self.estimator) for c in todo for s in self.seeds]
        results = execute(jobs, progress=False, pool=self.pool)
        stat = "rms_m" if self.metric == "rms" else "max_m"
        for i, c in enumerate(todo):
            rs = results[i * len(self.seeds):(i + 1) * len(self.seeds)]
            self.cache[c] = Simulated(c, [window_stat(r, WINDOW, stat) for r in rs], [r.error for r in rs if r.error])
            shown = f"{self.cache[c].value_m:.3f} m" if math.isfinite(self.cache[c].value_m) else f"failed ({'; '.join(self.cache[c].errors)[:120]})"
            self.say(f"simulated {c.label} ({c.n_tags(self.spec)} tags), {self.estimator} on seeds "
                     f"{self.seeds.start}-{self.seeds.stop - 1}: {shown}")
        return [self.cache[c] for c in candidates]

    def meets(self, c: Candidate, target_m: float, confident: bool = False) -> bool:
        """The layout's mean error over the seeds is at most ``target_m`` (``confident``: its 90 % upper limit)."""
        done = self.run([c])[0]
        v = done.upper_m if confident else done.value_m
        return math.isfinite(v) and v <= target_m


def _feasible_by_bound(search: BoundSearch, frontiers: dict[str, BoundEvaluation | None]) -> list[Candidate]:
    """The layouts at or denser than their family's frontier, cheapest first, one per tag count."""
    spec = search.spec
    out: list[Candidate] = []
    for family, ev in frontiers.items():
        if ev is None:
            continue
        grid = family_grid(spec, family)
        out += grid[:grid.index(ev.candidate) + 1]

    def key(c: Candidate) -> tuple[int, float]:
        known = search.cache.get(c)
        return c.n_tags(spec), known.value_m if known is not None and math.isfinite(known.value_m) else math.inf

    # one layout per tag count (the first family's, or the one of lower known bound): the bisection's steps are tag counts
    ranked = sorted(out, key=key)
    return [c for i, c in enumerate(ranked) if i == 0 or c.n_tags(spec) != ranked[i - 1].n_tags(spec)]


def _bisect_by_simulation(ordered: list[Candidate], meets: Callable[[Candidate], bool]) -> Candidate | None:
    """The first layout of ``ordered`` (cheapest first) that ``meets`` the target in simulation,
    by bisection (assuming more tags never hurt); None when none does. The densest layout
    is simulated only if the bisection gets there (it is the costliest to simulate)."""
    if not ordered:
        return None
    if meets(ordered[0]):
        return ordered[0]
    lo, hi = 0, len(ordered)  # lo fails; hi meets (len: not yet known)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if meets(ordered[mid]):
            hi = mid
        else:
            lo = mid
    return ordered[hi] if hi < len(ordered) else None


def _rivals(chosen: Candidate, ordered: list[Candidate], search: BoundSearch) -> list[Candidate]:
    """The chosen layout's two nearest cheaper rivals: the bound-feasible layouts just below it, else the nearest
    cheaper layouts the bound evaluated (those it ruled out)."""
    n = chosen.n_tags(search.spec)
    below = [c for c in ordered if c.n_tags(search.spec) < n][::-1]
    below += [e.candidate for e in search.cheaper(chosen) if e.candidate not in below]
    return below[:2]


def plan_layout(spec: TunnelSpec, folder: Path, target_m: float | None = None, budget: int | None = None,
                metric: str = "rms", estimator: str = "graph-batch", seeds: int = 2, fresh_seeds: int = 6,
                workers: int | None = None, progress: bool = True) -> PlanOutcome:
    """Plan the tunnel's tags and write the output folder (see the module docstring)."""
    from graphpos.registry import require_known

    started = time.perf_counter()
    if target_m is None and budget is None:
        raise ConfigError("plan-layout: give a target (--target-m) or a tag budget (--budget)")
    if target_m is not None and budget is not None:
        raise ConfigError("plan-layout: give either a target (--target-m) or a tag budget (--budget), not both")
    if target_m is not None and not (math.isfinite(target_m) and target_m > 0):
        raise ConfigError(f"plan-layout: the target must be a positive distance in metres, got {target_m!r}")
    if budget is not None and budget < 1:
        raise ConfigError(f"plan-layout: the tag budget must be at least 1, got {budget}")
    if seeds < 1 or fresh_seeds < 1:
        raise ConfigError(f"plan-layout: --seeds and --fresh-seeds must be at least 1, got {seeds} and {fresh_seeds}")
    if target_m is not None and fresh_seeds < 2:
        raise ConfigError("plan-layout: a target is confirmed by the 90 % upper limit of the mean over the fresh drives, "
                          f"which one drive does not give: --fresh-seeds must be at least 2, got {fresh_seeds}")
    classes = require_known(["graph-batch", estimator])
    carried = set(sensor_set(spec.sensors))
    for cls, what in ((classes["graph-batch"], "the bound (graph-batch's graph)"), (classes[estimator], estimator)):
        if not (set(cls.required_channels) <= carried and all(carried & set(group) for group in cls.required_any)):
            raise ConfigError(f"plan-layout: {what} needs {cls.needs()}; the vehicle's sensors are {spec.sensors}")
    kind = bound_kind(estimator)

    def say(line: str) -> None:
        if progress:
            print(f"plan-layout: {line}", file=sys.stderr, flush=True)

    search = BoundSearch(spec, kind=kind, metric=metric, progress=say)
    folder = Path(folder)
    with output_folder(folder, "results.json") as out, executor(workers) as pool:
        sim = _Simulator(spec, estimator, range(seeds), metric, pool, say)
        fresh = _Simulator(spec, estimator, range(FRESH_SEED, FRESH_SEED + fresh_seeds), metric, pool, say)
        if target_m is not None:
            frontiers = search.frontiers(target_m, pool=pool)
            ordered = _feasible_by_bound(search, frontiers)
            t_bound = time.perf_counter() - started
            def on_search_seeds(c: Candidate) -> bool:
                return sim.meets(c, target_m)

            def confirmed(c: Candidate) -> bool:  # fresh seeds only for a layout that meets on the search's
                return on_search_seeds(c) and fresh.meets(c, target_m, confident=True)

            chosen = _bisect_by_simulation(ordered, on_search_seeds)
            while chosen is not None and not fresh.meets(chosen, target_m, confident=True):
                # it met on the search's seeds, not on fresh ones: the next denser layout that meets on the
                # search's seeds (their runs are cached) is confirmed in turn
                chosen = _bisect_by_simulation([c for c in ordered if c.n_tags(spec) > chosen.n_tags(spec)], on_search_seeds)
            rivals = ordered[-2:][::-1]
            while chosen is not None:
                # a cheaper rival that meets the target too (simulated errors are noisy) takes the choice over
                rivals = _rivals(chosen, ordered, search)
                better = [c for c in rivals if confirmed(c)]
                if not better:
                    break
                chosen = min(better, key=lambda c: c.n_tags(spec))
        else:
            frontiers = search.within_budget(budget)
            ranked = sorted((e for e in frontiers.values() if e is not None and math.isfinite(e.value_m)), key=lambda e: e.value_m)
            t_bound = time.perf_counter() - started
            chosen = ranked[0].candidate if ranked else None
            rivals = [e.candidate for e in ranked[1:3]]
        shown = ([chosen] if chosen is not None else []) + rivals
        for c in shown:
            search.evaluate(c)
        sim.run(shown)
        if chosen is not None:
            fresh.run([chosen])
        met = chosen is not None and (target_m is None or confirmed(chosen))
        took = time.perf_counter() - started
        _write(out, spec, search, sim, fresh, frontiers, chosen, rivals, target_m, budget, metric, estimator, kind, seeds,
               met, t_bound, took)
        say(f"done in {took:.0f} s: " + (f"{chosen.label}, {chosen.n_tags(spec)} tags" if chosen is not None else "no layout found"))
    return PlanOutcome(folder, chosen, met)


def _layout_toml(spec: TunnelSpec, chosen: Candidate) -> str:
    from graphpos.sim.params import to_toml

    head = (f"# graphpos plan-layout: {chosen.label}, {chosen.n_tags(spec)} tags, for a tunnel {spec.describe()}.\n"
            f"# Simulate a drive with it:  graphpos simulate {BASE_SCENARIO} --pattern {spec.pattern} --config layout.toml\n"
            "# tags.family_spacing_m is between tags on one wall (between group starts for groups), "
            "measured from the entry portal.\n\n")
    return head + to_toml({**spec.overrides(), "tags": chosen.tags()})


def _row(spec: TunnelSpec, search: BoundSearch, sims: tuple[_Simulator, _Simulator], c: Candidate, role: str,
         target_m: float | None) -> list[str]:
    b = search.cache[c].value_m
    searched, fresh = (s.cache.get(c) for s in sims)
    mean = searched.value_m if searched else math.nan
    fresh_cell = f"{fmt(fresh.value_m, 3)} ({fmt(fresh.upper_m, 3)})" if fresh else "–"
    if target_m is None or not math.isfinite(mean):
        meets = "—"
    else:
        meets = "yes" if mean <= target_m and (fresh is None or fresh.upper_m <= target_m) else "no"
        meets += "" if fresh is not None or mean > target_m else " (search seeds)"
    eff = mean / b if math.isfinite(mean) and math.isfinite(b) and b > 0 else math.nan
    return [role, c.label, str(c.n_tags(spec)), fmt(b, 3), fmt(mean, 3), fresh_cell, fmt(eff, 2), meets]


def _write(out: Path, spec: TunnelSpec, search: BoundSearch, sim: _Simulator, fresh: _Simulator, frontiers, chosen, rivals, target_m, budget,
           metric, estimator, kind, seeds, met, t_bound, took) -> None:
    what = f"{metric.upper()} position error in the tunnel"
    goal = f"target {what} at most {target_m:g} m" if target_m is not None else f"budget of {budget} tags"
    report = Report("graphpos plan-layout")
    sec = report.section("The plan")
    sec.text(f"Tunnel {spec.describe()}; {goal}; the target is held against {estimator} ({kind} output, so the "
             f"{kind} bound) over {seeds} simulated drive(s).")
    if chosen is None:
        sec.text("**No layout found**: " + ("no layout of any family meets the target in simulation, up to the densest "
                                            "searched (3 m between tags on a wall)." if target_m is not None else
                                            "no family fits the budget."))
    else:
        sec.text(f"**Chosen: {chosen.label}, {chosen.n_tags(spec)} tags** — "
                 + ("meets the target in simulation." if met else "does not meet the target in simulation.")
                 + " Its simulator parameters are in `layout.toml`.")
    pair = (sim, fresh)
    rows = ([_row(spec, search, pair, chosen, "chosen", target_m)] if chosen is not None else [])
    rows += [_row(spec, search, pair, c, f"rival {i + 1}", target_m) for i, c in enumerate(rivals)]
    fresh_span = f"{fresh.seeds.start}-{fresh.seeds.stop - 1}"
    sec.table(["", "layout", "tags", f"bound ({kind}) [m]", f"{estimator}, seeds 0-{seeds - 1} [m]",
               f"{estimator}, fresh seeds {fresh_span}: mean (90 % upper) [m]", "efficiency", "meets"], rows,
              caption=f"{what}: the bound (a lower limit for any estimator on these sensors) and the estimator's "
                      f"simulated error, mean over the search's seeds 0-{seeds - 1} and over fresh seeds {fresh_span} "
                      "(the chosen layout must meet the target with the first's mean and the second's 90 % upper "
                      "confidence limit); efficiency = simulated (search seeds) / bound.")
    if target_m is not None:
        fr_rows = [[f, str(e.n_tags) if e else "—", e.candidate.label if e else "not even the densest", fmt(e.value_m, 3) if e else "—"]
                   for f, e in frontiers.items()]
        report.section("What the bound rules out").table(
            ["family", "fewest tags", "layout", "bound [m]"], fr_rows,
            caption="Per family, the fewest tags whose bound meets the target: with fewer, no estimator on these "
                    "sensors can meet it. Found by bisection over the family's spacings.")
    if chosen is not None:
        curves = [search.cache[c] for c in [chosen] + rivals]
        simulated = [sim.cache[c].value_m if c in sim.cache else math.nan for c in [chosen] + rivals]
        fig = plots.plan_bounds(curves, simulated, out / "plan.png", kind, target_m, f"{spec.describe()}", spec.length_m)
        report.section("The bound along the tunnel").figure(
            fig, caption=f"sqrt(trace) of the {kind} position bound against distance from the entry portal "
                         f"(simulated drive, seed 0) for the chosen layout and its rivals, and their simulated {metric.upper()} "
                         f"error in the tunnel (dashed, search seeds); below, the chosen tags on the walls.")
        write_atomically(out / "layout.toml", _layout_toml(spec, chosen).encode())
    ev_rows = [[e.candidate.label, str(e.n_tags), fmt(e.value_m, 3), f"{e.seconds:.1f}"]
               for e in sorted(search.cache.values(), key=lambda e: (e.candidate.family, -e.n_tags))]
    report.section("Every bound evaluated").table(["layout", "tags", "bound [m]", "seconds"], ev_rows)
    runs = len(sim.cache) * len(sim.seeds) + len(fresh.cache) * len(fresh.seeds)
    report.section("Run").text(f"{len(search.cache)} bounds and {runs} simulated runs in {took:.0f} s; "
                               f"the bound search took {t_bound:.0f} s.")

    def record(c: Candidate) -> dict[str, Any]:
        e = search.cache.get(c)
        s = sim.cache.get(c)
        f = fresh.cache.get(c)
        return {"layout": c.label, "tags": c.tags(), "n_tags": c.n_tags(spec),
                "bound_m": e.value_m if e else None, "bound_error": e.error if e else None,
                "simulated_m": s.value_m if s else None, "simulated_per_seed_m": s.per_seed_m if s else None,
                "simulation_errors": s.errors if s else None,
                "fresh_simulated_m": f.value_m if f else None, "fresh_upper_90_m": f.upper_m if f else None,
                "fresh_per_seed_m": f.per_seed_m if f else None}

    write_json(out / "results.json", {
        "command": "plan-layout", "tunnel": spec.__dict__ | {"overrides": spec.overrides()},
        "target_m": target_m, "budget": budget, "metric": metric, "window": WINDOW, "estimator": estimator,
        "bound_kind": kind, "seeds": list(sim.seeds), "fresh_seeds": list(fresh.seeds), "met": met,
        "chosen": record(chosen) if chosen is not None else None, "rivals": [record(c) for c in rivals],
        "frontiers": {f: (record(e.candidate) if e else None) for f, e in frontiers.items()},
        "bounds": [record(e.candidate) for e in search.cache.values()],
        "bound_search_s": t_bound, "wall_time_s": took, "provenance": provenance(),
    })
    report.write(out)

