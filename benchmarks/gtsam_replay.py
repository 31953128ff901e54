"""Record the GTSAM solving calls an estimator makes, and replay them alone (issue 19).

The replay measures the GTSAM-only cost of an estimator's run: the same
iSAM2 / fixed-lag updates, estimate reads, marginal covariances,
Levenberg-Marquardt solves and batch marginals, in the same order, on fresh
GTSAM objects, without any of the Python that built the factors. An
estimator's CPU divided by its replay's is then the overhead of the Python
around GTSAM (1.0: none).

Usage, inside a benchmark process only (the recorder monkeypatches
:mod:`graphpos.graph` while it is active and restores it on exit)::

    with Recorder() as rec:
        est = ESTIMATORS["graph-isam2"]().run(drive.without_truth())
    replay = rec.replay()          # timed with time.process_time()
    replay.check()                 # raises ReplayMismatch unless every result is reproduced

What is recorded
----------------
- every :class:`graphpos.graph.smoothers.FixedLagSmoother` constructed
  (graph-isam2's and graph-batch's windowed iSAM2 is one; its model name,
  lag), and every call made on its GTSAM object (``smoother``, and its inner
  iSAM2 from ``getISAM2()``): ``update`` (the forced relinearisations of
  :func:`~graphpos.graph.smoothers.relinearise` and graph-isam2's range
  rebuild with removed factor indices included), ``calculateEstimate*``,
  ``calculateBestEstimate`` and ``marginalCovariance``, each with a copy of
  its inputs and its result;
- every :func:`graphpos.graph.estimators.optimise` (Levenberg-Marquardt plus
  its error check) call, through every module binding of the name
  (:mod:`graphpos.graph.estimators`, :mod:`graphpos.graph.ranges`;
  :mod:`graphpos.graph.calibration` imports it at call time);
- every ``gtsam.Marginals`` built (a copy of its graph and values: the
  factorisation) and every ``marginalCovariance``,
  ``jointMarginalCovariance`` (its full matrix) and
  ``deleteCachedShortcuts`` call on it: graph-batch's covariances
  (:func:`~graphpos.graph.estimators.marginal_covariances`) and the joint
  marginals of its heading-noise fit
  (:func:`~graphpos.graph.calibration.turn_redundancy`).

Not recorded (not GTSAM solving): factor and graph building, reads of plain
``gtsam.Values`` (``ValuesSource``), ``getFactorsUnsafe``, and the
``graph.error`` of range-scale calibration's scale search.

While recording, the recorder also splits the recorded run's CPU
(``time.process_time``) into ``GraphBuilder.add``/``flush`` (per-measurement
Python), ``GraphBuilder.graph`` (whole-graph rebuilds), the recorded GTSAM
calls, the recorder's own copying, and the rest. The recording run is
slower than a plain one by its copies and timers: time estimators in a
separate, unrecorded run.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import gtsam
import numpy as np

#: Largest difference a replayed result may have from the recorded one.
TOLERANCE = 1e-9


class ReplayMismatch(AssertionError):
    """The replay did not reproduce the estimator's GTSAM results."""


def _copy_graph(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    out = gtsam.NonlinearFactorGraph()
    out.push_back(graph)
    return out


def _copy_update_params(p: gtsam.ISAM2UpdateParams) -> dict[str, Any]:
    fields = {"force_relinearize": p.force_relinearize, "forceFullSolve": p.forceFullSolve, "removeFactorIndices": list(p.removeFactorIndices)}
    for name in ("constrainedKeys", "noRelinKeys", "extraReelimKeys", "newAffectedKeys"):
        if getattr(p, name) is not None:
            raise NotImplementedError(f"gtsam_replay: ISAM2UpdateParams.{name} is not recorded")
    return fields


def _update_params(fields: dict[str, Any]) -> gtsam.ISAM2UpdateParams:
    p = gtsam.ISAM2UpdateParams()
    p.force_relinearize = fields["force_relinearize"]
    p.forceFullSolve = fields["forceFullSolve"]
    p.removeFactorIndices = fields["removeFactorIndices"]
    return p


def _copy_result(x: Any) -> Any:
    if isinstance(x, gtsam.Values):
        return gtsam.Values(x)
    if isinstance(x, np.ndarray):
        return x.copy()
    return x


def _difference(a: Any, b: Any) -> float:
    """Largest difference between two GTSAM results (inf where they do not compare)."""
    if isinstance(a, gtsam.Values):
        if a.size() != b.size() or list(a.keys()) != list(b.keys()):
            return np.inf
        return 0.0 if a.equals(b, TOLERANCE) else np.inf
    if isinstance(a, (list, tuple)):
        return max((_difference(x, y) for x, y in zip(a, b, strict=True)), default=0.0)
    if isinstance(a, (np.ndarray, float, int)):
        a, b = np.asarray(a, float), np.asarray(b, float)
        return float(np.max(np.abs(a - b), initial=0.0)) if a.shape == b.shape else np.inf
    if hasattr(a, "equals"):
        return 0.0 if a.equals(b, TOLERANCE) else np.inf
    raise TypeError(f"gtsam_replay: cannot compare {type(a).__name__}")


@dataclasses.dataclass
class Split:
    """CPU of the recorded run, s, by where it was spent."""

    total_s: float = 0.0
    builder_add_s: float = 0.0  # GraphBuilder.add + flush: per-measurement Python
    builder_graph_s: float = 0.0  # GraphBuilder.graph: whole-graph rebuilds for the batch solves
    gtsam_s: float = 0.0  # the recorded calls (smoothers, LM, marginals), pybind conversions included
    recording_s: float = 0.0  # this recorder's copies of inputs and results

    @property
    def rest_s(self) -> float:
        return self.total_s - self.builder_add_s - self.builder_graph_s - self.gtsam_s - self.recording_s

    @property
    def in_run_ratio(self) -> float:
        """The recorded run's CPU less the recorder's copies, over its GTSAM calls' CPU: one run, no drift between runs."""
        return (self.total_s - self.recording_s) / self.gtsam_s if self.gtsam_s > 0 else float("nan")

    def describe(self) -> str:
        return (f"builder.add/flush {self.builder_add_s:.2f} s, builder.graph {self.builder_graph_s:.2f} s, "
                f"GTSAM {self.gtsam_s:.2f} s, rest {self.rest_s:.2f} s (recorded run {self.total_s:.2f} s, of which recorder copies {self.recording_s:.2f} s; "
                f"run less copies / its GTSAM: {self.in_run_ratio:.2f}x)")


class _Proxy:
    """Stands in for a GTSAM smoother object and records the solving calls made on it."""

    def __init__(self, rec: "Recorder", sid: int, target: str, obj: Any):
        self._rec, self._sid, self._target, self._obj = rec, sid, target, obj

    def update(self, *args, **kwargs):
        if kwargs:
            raise NotImplementedError(f"gtsam_replay: keyword arguments to update ({sorted(kwargs)}) are not recorded")
        c = time.process_time()
        copied = []
        for a in args:
            if isinstance(a, gtsam.NonlinearFactorGraph):
                copied.append(("graph", _copy_graph(a)))
            elif isinstance(a, gtsam.Values):
                copied.append(("values", gtsam.Values(a)))
            elif isinstance(a, gtsam.ISAM2UpdateParams):
                copied.append(("params", _copy_update_params(a)))
            elif isinstance(a, dict):
                copied.append(("plain", dict(a)))
            elif isinstance(a, (list, tuple)):
                copied.append(("plain", list(a)))
            else:
                raise NotImplementedError(f"gtsam_replay: update argument {type(a).__name__} is not recorded")
        g = time.process_time()
        self._rec.split.recording_s += g - c
        out = self._obj.update(*args)
        self._rec.split.gtsam_s += time.process_time() - g
        self._rec.calls.append(("update", self._sid, self._target, copied, None))
        return out

    def getISAM2(self):
        return _Proxy(self._rec, self._sid, "inner-isam2", self._obj.getISAM2())

    def __getattr__(self, name: str):
        attr = getattr(self._obj, name)
        if not (name.startswith("calculate") or name == "marginalCovariance"):
            return attr

        def recorded(*args):
            g = time.process_time()
            out = attr(*args)
            c = time.process_time()
            self._rec.split.gtsam_s += c - g
            self._rec.calls.append(("call", self._sid, self._target, (name, *args), _copy_result(out)))
            self._rec.split.recording_s += time.process_time() - c
            return out

        return recorded


class _MarginalsProxy:
    """Stands in for a ``gtsam.Marginals`` and records its construction and the covariances asked of it."""

    def __init__(self, rec: "Recorder", real: type, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values):
        c = time.process_time()
        inputs = (_copy_graph(graph), gtsam.Values(values))
        g = time.process_time()
        self._obj = real(graph, values)
        e = time.process_time()
        self._rec, self._mid = rec, len(rec.marginals)
        rec.marginals.append(None)
        rec.calls.append(("marginals", self._mid, None, inputs, None))
        rec.split.gtsam_s += e - g
        rec.split.recording_s += (g - c) + (time.process_time() - e)

    def __getattr__(self, name: str):
        if name not in ("marginalCovariance", "jointMarginalCovariance", "deleteCachedShortcuts"):
            raise NotImplementedError(f"gtsam_replay: Marginals.{name} is not recorded")
        attr = getattr(self._obj, name)

        def recorded(*args):
            g = time.process_time()
            out = attr(*args)
            kept = out.fullMatrix() if name == "jointMarginalCovariance" else out
            c = time.process_time()
            self._rec.split.gtsam_s += c - g
            self._rec.calls.append(("marginals-call", self._mid, None, (name, *args), _copy_result(kept)))
            self._rec.split.recording_s += time.process_time() - c
            return out

        return recorded


class Recorder:
    """Context manager: record the GTSAM solving calls of the estimators run inside it (see the module docstring)."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.smoothers: list[tuple] = []  # (kind, model_name, lag_s) by smoother id
        self.marginals: list[None] = []  # one entry per gtsam.Marginals built (its id)
        self.split = Split()
        self._undo: list[tuple[Any, str, Any]] = []

    # -- patching -----------------------------------------------------------
    def _patch(self, owner: Any, name: str, new: Any) -> None:
        self._undo.append((owner, name, owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)))
        setattr(owner, name, new)

    def __enter__(self) -> "Recorder":
        from graphpos.graph import builder, estimators, ranges, smoothers

        rec = self
        lag_init = smoothers.FixedLagSmoother.__init__

        def fixed_lag_init(obj, model_name: str, lag_s: float, **kwargs):
            lag_init(obj, model_name, lag_s, **kwargs)  # the timestamps it floors reach the recorded updates as floored
            sid = len(rec.smoothers)
            rec.smoothers.append(("fixed-lag", model_name, lag_s))
            rec.calls.append(("new", sid, None, None, None))
            obj.smoother = _Proxy(rec, sid, "fixed-lag", obj.smoother)

        optimise, real_marginals = estimators.optimise, gtsam.Marginals

        def recorded_optimise(graph, initial, config, what, relative_tol=1e-4):
            c = time.process_time()
            inputs = (_copy_graph(graph), gtsam.Values(initial), int(config.batch_max_iterations), float(relative_tol))
            g = time.process_time()
            out = optimise(graph, initial, config, what, relative_tol)
            e = time.process_time()
            rec.calls.append(("lm", None, None, inputs, gtsam.Values(out)))
            rec.split.gtsam_s += e - g
            rec.split.recording_s += (g - c) + (time.process_time() - e)
            return out

        def timed(fn, field):
            def wrapper(*args, **kwargs):
                c = time.process_time()
                try:
                    return fn(*args, **kwargs)
                finally:
                    setattr(rec.split, field, getattr(rec.split, field) + time.process_time() - c)
            return wrapper

        self._patch(smoothers.FixedLagSmoother, "__init__", fixed_lag_init)
        for module in (estimators, ranges):
            self._patch(module, "optimise", recorded_optimise)
        self._patch(gtsam, "Marginals", lambda graph, values: _MarginalsProxy(rec, real_marginals, graph, values))
        self._patch(builder.GraphBuilder, "add", timed(builder.GraphBuilder.add, "builder_add_s"))
        self._patch(builder.GraphBuilder, "flush", timed(builder.GraphBuilder.flush, "builder_add_s"))
        self._patch(builder.GraphBuilder, "graph", timed(builder.GraphBuilder.graph, "builder_graph_s"))
        self._c0 = time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.split.total_s += time.process_time() - self._c0
        for owner, name, old in reversed(self._undo):
            setattr(owner, name, old)
        self._undo.clear()

    # -- replay ---------------------------------------------------------------
    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for kind, _, target, args, _ in self.calls:
            label = args[0] if kind in ("call", "marginals-call") else kind
            out[label] = out.get(label, 0) + 1
        return out

    def replay(self) -> "Replay":
        """Redo every recorded call, in order, on fresh GTSAM objects; CPU timed with ``time.process_time``."""
        from graphpos.graph.smoothers import isam2_params

        objects: list[Any] = [None] * len(self.smoothers)
        marginals: list[Any] = [None] * len(self.marginals)
        outputs: list[Any] = []
        c0 = time.process_time()
        for kind, sid, target, args, _ in self.calls:
            if kind == "new":
                _, model_name, lag_s = self.smoothers[sid]
                objects[sid] = gtsam.IncrementalFixedLagSmoother(lag_s, isam2_params(model_name, find_unused_factor_slots=True))
                outputs.append(None)
            elif kind == "update":
                obj = objects[sid].getISAM2() if target == "inner-isam2" else objects[sid]
                obj.update(*(_update_params(a) if tag == "params" else a for tag, a in args))
                outputs.append(None)
            elif kind == "call":
                obj = objects[sid].getISAM2() if target == "inner-isam2" else objects[sid]
                outputs.append(getattr(obj, args[0])(*args[1:]))
            elif kind == "lm":
                graph, initial, max_iterations, relative_tol = args
                params = gtsam.LevenbergMarquardtParams()
                params.setMaxIterations(max_iterations)
                params.setRelativeErrorTol(relative_tol)
                params.setAbsoluteErrorTol(1e-6)
                result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
                graph.error(result)  # optimise's divergence check
                outputs.append(result)
            elif kind == "marginals":
                graph, values = args
                marginals[sid] = gtsam.Marginals(graph, values)
                outputs.append(None)
            elif kind == "marginals-call":
                out = getattr(marginals[sid], args[0])(*args[1:])
                outputs.append(out.fullMatrix() if args[0] == "jointMarginalCovariance" else out)
            else:
                raise AssertionError(kind)
        cpu_s = time.process_time() - c0
        return Replay(self, outputs, cpu_s)


@dataclasses.dataclass
class Replay:
    recorder: Recorder
    outputs: list[Any]
    cpu_s: float

    def max_difference(self) -> tuple[float, str]:
        """Largest difference of a replayed result from the recorded one, and which call it was."""
        worst, where = 0.0, "none"
        for i, ((kind, sid, target, args, recorded), out) in enumerate(zip(self.recorder.calls, self.outputs, strict=True)):
            if recorded is None:
                continue
            d = _difference(recorded, out)
            if not d <= worst:  # NaN counts as worst
                label = args[0] if kind in ("call", "marginals-call") else kind
                worst, where = d, f"call {i} ({label})"
        return worst, where

    def check(self) -> None:
        """Raise :class:`ReplayMismatch` unless the replay reproduced every recorded result to :data:`TOLERANCE`."""
        if not self.recorder.calls:
            raise ReplayMismatch("nothing was recorded")
        worst, where = self.max_difference()
        if not worst <= TOLERANCE:
            raise ReplayMismatch(f"replay differs from the recorded run at {where}: by {worst:g} (inf: beyond {TOLERANCE:g} by GTSAM's equals)")
