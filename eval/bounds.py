"""The posterior Cramer-Rao bound in the reports (issue 18, items 2 and 4): bound rows and efficiencies.

:func:`drive_bound` computes the position bound of one (drive, layout) once
(:func:`graphpos.bound.position_bound`), turning a failure into a reason
string (a drive without truth, or one graph-batch never starts on, shows
"—" and why; nothing crashes). :func:`drive_bounds` computes several in
the executor's workers (:func:`eval.execution.executor`), each from its job
source, so that a sweep ships sources, not drives.

Efficiency is an estimator's RMS position error over a window divided by
the RMS of the matching bound over the same window (:func:`efficiency`):
1 is the best the information allows, above 1 is what the estimator leaves.
The matching bound (:func:`bound_kind`) is the smoother bound for the
estimators that use later data (:data:`SMOOTHED_ESTIMATORS`: graph-batch,
graph-fixed-lag-smoothed and graph-ranges, which smooths its ranges over
the whole drive), and the filtering bound for the causal ones (the filters, graph-isam2,
graph-fixed-lag). graph-fixed-lag-smoothed sees only a few seconds of later
data: the smoother bound is a valid but loose bound for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np
from tqdm import tqdm

from eval.execution import executor, load_drive
from eval.metrics import WHOLE
from eval.report import mean_spread
from graphpos.drive import Drive

#: The two bounds of :class:`graphpos.bound.Bound`.
KINDS = ("smoother", "filtering")
#: Estimators whose output uses data after its epoch: scored against the smoother bound.
SMOOTHED_ESTIMATORS = frozenset({"graph-batch", "graph-fixed-lag-smoothed", "graph-ranges"})
#: Row labels of the bounds in the report tables.
BOUND_LABELS = {kind: f"bound ({kind})" for kind in KINDS}
#: A table cell without a bound figure.
NO_BOUND = "—"


def bound_kind(estimator: str) -> str:
    """The bound an estimator is scored against: ``"smoother"`` or ``"filtering"``."""
    return "smoother" if estimator in SMOOTHED_ESTIMATORS else "filtering"


def bound_label(estimator: str) -> str:
    """How an efficiency cell names the bound it is against: :func:`bound_kind`, and for an estimator on
    RFID ranges only that the bound's sensors are more than its own (the bound is of the drive's
    odometry, compass and ranges together; one of ranges alone would be higher, its efficiency lower)."""
    from eval.names import RFID_ONLY, sensors_of

    kind = bound_kind(estimator)
    return f"{kind}, of more sensors" if sensors_of(estimator) == RFID_ONLY else kind


@dataclass
class DriveBound:
    """The bound of one (drive, layout), or why there is none.

    Attributes
    ----------
    drive_name : str
    layout : str or None
    bound : graphpos.bound.Bound or None
    reason : str or None
        Why there is no bound (None when there is one).
    """

    drive_name: str
    layout: str | None = None
    bound: Any = None
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.bound is not None

    def rms_m(self, window: str = WHOLE, kind: str = "smoother") -> float:
        """RMS over a window (a drive window label or :data:`~eval.metrics.WHOLE`) of sqrt(trace) of the
        bound, m; NaN without a bound or without the window."""
        if self.bound is None:
            return math.nan
        try:
            return self.bound.rms_sqrt_trace(None if window == WHOLE else window, kind)
        except KeyError:  # the drive has no such window
            return math.nan

    def efficiency(self, estimator: str, rms_m: float, window: str = WHOLE) -> float:
        """:func:`efficiency` of an estimator's RMS against its matching bound in a window."""
        return efficiency(rms_m, self.rms_m(window, bound_kind(estimator)))

    def cell(self, window: str = WHOLE, kind: str = "smoother", digits: int = 2, width: int = 90) -> str:
        """The bound's RMS in a window for a table cell, or "— (reason)" (at most ``width`` characters;
        the full reason is in results.json)."""
        if self.bound is None:
            text = f"{NO_BOUND} ({self.reason})"
            return text if len(text) <= width else text[: width - 2] + "…)"
        v = self.rms_m(window, kind)
        return f"{v:.{digits}f}" if np.isfinite(v) else NO_BOUND

    @property
    def is_limit(self) -> bool:
        """Whether the bound is a lower limit: built with the drive's own noise levels (a simulated drive), not
        graph-batch's defaults (:func:`graphpos.bound.pcrb.knows_noise_levels`)."""
        return self.bound is not None and bool(self.bound.diagnostics.get("noise_levels_known"))

    def windows(self) -> list[str]:
        """:data:`~eval.metrics.WHOLE` and the labels of the drive's windows (none without a bound)."""
        if self.bound is None:
            return [WHOLE]
        return [WHOLE] + list(dict.fromkeys(w.label for w in self.bound.windows))

    def timing(self) -> dict[str, float] | None:
        """Wall times of the bound's parts (s): build, smoother, filtering, total."""
        if self.bound is None:
            return None
        d = self.bound.diagnostics
        return {k: d[k] for k in ("build_s", "smoother_s", "filtering_s", "total_s") if k in d}

    def record(self, windows: Iterable[str]) -> dict[str, Any]:
        """The bound as stored in results.json: RMS per window of each kind, timing, keyframes, reason."""
        windows = list(windows)
        return {"drive": self.drive_name, "layout": self.layout, "reason": self.reason,
                **{f"{kind}_rms_m": {w: self.rms_m(w, kind) for w in windows} for kind in KINDS},
                "timing_s": self.timing(), "is_limit": self.is_limit,
                "keyframes": self.bound.diagnostics.get("keyframes") if self.bound is not None else None}


def bounds_cell(bounds: list[DriveBound], window: str, kind: str, scale: float = 1.0, prefix: str = "",
                empty: str = "–") -> str:
    """A table cell of the bounds of several drives (seeds): mean ± STD of ``scale`` x their RMS in a
    window (``prefix`` before it), how many drives have none, or why when none has; ``empty`` without drives."""
    if not bounds:
        return empty
    good = [b for b in bounds if b.ok]
    if not good:
        return bounds[0].cell(window, kind, width=60)
    text = prefix + mean_spread([scale * b.rms_m(window, kind) for b in good])
    failed = len(bounds) - len(good)
    return text + (f" ({failed} of {len(bounds)} drives without a bound)" if failed else "")


def efficiency(rms_m: float, bound_rms_m: float) -> float:
    """Estimator RMS over the matching bound's RMS (NaN when either is missing or the bound is 0)."""
    if not (np.isfinite(rms_m) and np.isfinite(bound_rms_m)) or bound_rms_m <= 0:
        return math.nan
    return float(rms_m / bound_rms_m)


def result_efficiency(result: Any, bound: DriveBound, window: str = WHOLE) -> float:
    """:meth:`DriveBound.efficiency` of a job result (:class:`eval.execution.JobResult`) in a window;
    NaN when the run failed or lacks the window."""
    w = result.metrics["windows"].get(window) if result.ok else None
    return bound.efficiency(result.job.estimator, w["position"]["rms_m"], window) if w else math.nan


def drive_bound(drive: Drive, layout: str | None = None) -> DriveBound:
    """The bound of a drive heard through a tag layout (:func:`graphpos.bound.position_bound` with the
    drive's own noise levels); never raises: a failure is the result's ``reason``."""
    from graphpos.bound import position_bound

    try:
        return DriveBound(drive.name, layout, position_bound(drive, layout=layout))
    except Exception as exc:  # EstimationError, MissingChannelError, or a bug: said in the cell, not raised
        return DriveBound(drive.name, layout, reason=f"{type(exc).__name__}: {exc}")


def source_bound(source: Any, layout: str | None = None) -> DriveBound:
    """:func:`drive_bound` of a job source (:func:`eval.execution.load_drive`); never raises."""
    try:
        drive = load_drive(source)
    except Exception as exc:  # the drive itself does not load: said in the cell
        return DriveBound(_source_name(source), layout, reason=f"{type(exc).__name__}: {exc}")
    return drive_bound(drive, layout)


def drive_bounds(keys: list[tuple[Any, str | None]], workers: int | None = None,
                 scheduler: str | None = None, progress: bool = False) -> list[DriveBound]:
    """:func:`source_bound` of each (source, layout), computed in the executor's workers; in the order of ``keys``
    (``progress``: a bar on stderr, as the runs have)."""
    if not keys:
        return []
    with executor(workers, scheduler, tasks=len(keys)) as pool:
        futures = [pool.submit(source_bound, *key) for key in keys]
        out = []
        for (source, layout), fut in zip(keys, tqdm(futures, desc="bounds", unit="drive", disable=not progress, leave=False)):
            try:
                out.append(fut.result())
            except Exception as exc:  # the worker itself died
                out.append(DriveBound(_source_name(source), layout, reason=f"worker failed: {type(exc).__name__}: {exc}"))
    return out


def _source_name(source: Any) -> str:
    """A drive's name, or a source's description."""
    return source.name if isinstance(source, Drive) else repr(source)
