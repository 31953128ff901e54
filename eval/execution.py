"""Run (drive, estimator) jobs on a local process pool or a Dask cluster.

A job names where its drive comes from (a file, a simulation recipe, or the
drive itself) rather than carrying it, so a sweep of hundreds of simulated
drives ships a few bytes per job and each worker builds its drive, keeping
a small cache so that several estimators on the same drive do not rebuild it.
The worker hands the estimator the drive without its truth
(:meth:`graphpos.drive.Drive.without_truth`: truth is for scoring only,
issue 13), scores the estimate against the full drive afterwards
(:func:`eval.metrics.evaluate_estimate`) and sends back the figures, and the
estimate only when asked (plots and exports need it; big sweeps do not).

A failing job does not stop the sweep: its result carries the error (a
:class:`~graphpos.errors.GraphposError` message, or the exception type,
message and traceback of anything else), and the callers report it.

Both back-ends are a :class:`concurrent.futures.Executor`: a
:class:`~concurrent.futures.ProcessPoolExecutor` by default, or
``distributed.Client(address).get_executor()`` when a scheduler address is
given.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import time
import traceback
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from typing import Any, Iterator

from tqdm import tqdm

from graphpos.drive import Drive
from graphpos.errors import ConfigError, GraphposError, MissingChannelError


@dataclass(frozen=True)
class FileSource:
    """A drive in an MCAP file."""

    path: str

    def load(self) -> Drive:
        from graphpos.io import read_drive

        return read_drive(self.path)

    def describe(self) -> dict[str, Any]:
        return {"file": self.path}


@dataclass(frozen=True)
class SimSource:
    """A simulated drive: the arguments of :func:`graphpos.sim.simulate`.

    ``overrides_json`` and ``faults_json`` hold the (nested) parameter
    overrides and fault specs as JSON so that the source hashes and caches.
    """

    scenario: str
    pattern: str | None = None
    seed: int = 0
    duration_s: float | None = None
    overrides_json: str = ""
    rfid_latency_s: tuple[float, float] | None = None
    faults_json: str = ""

    def load(self) -> Drive:
        from graphpos.sim import simulate

        return simulate(
            self.scenario,
            pattern=self.pattern,
            seed=self.seed,
            duration_s=self.duration_s,
            overrides=json.loads(self.overrides_json) if self.overrides_json else None,
            rfid_latency_s=self.rfid_latency_s,
            faults=json.loads(self.faults_json) if self.faults_json else None,
        )

    def describe(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["overrides"] = json.loads(out.pop("overrides_json") or "{}")
        out["faults"] = json.loads(out.pop("faults_json") or "{}")
        return out


@functools.lru_cache(maxsize=4)
def _load_cached(source: FileSource | SimSource) -> Drive:
    return source.load()


def load_drive(source: FileSource | SimSource | Drive) -> Drive:
    """The drive of a source (a :class:`Drive` is its own source)."""
    return source if isinstance(source, Drive) else _load_cached(source)


@dataclass(frozen=True)
class Job:
    """One estimator on one drive.

    Parameters
    ----------
    source : FileSource, SimSource or Drive
    estimator : str
        Registry name.
    layout : str, optional
        Tag layout the estimator hears.
    range_model : str, RangeModel or None
        A saved model's path, a model, or None for the drive's default.
    settings : dict
        ``{key: value text}`` changes to the estimator's default config
        (:mod:`graphpos.settings`).
    initial_pose : graphpos.ignition.StartPose, optional
        A start pose the user gives (``--initial-pose``), passed to the
        estimator; None: the drive's stored one, else ignition.
    profile : graphpos.profile.SensorProfile, optional
        A sensor profile (``--profile``), passed to the estimator.
    keep_estimate : bool
        Send the estimate back (for plots and exports).
    hold_last_output : bool
        Score the estimate with its last output held to the end of the
        drive (:func:`eval.metrics.held_to_end`); the estimate sent back
        is the estimator's own.
    tag : dict
        The caller's labels (experiment, pattern, seed ...), returned as given.
    """

    source: Any
    estimator: str
    layout: str | None = None
    range_model: Any = None
    settings: dict[str, str] = field(default_factory=dict)
    initial_pose: Any = None
    profile: Any = None
    keep_estimate: bool = False
    hold_last_output: bool = False
    tag: dict[str, Any] = field(default_factory=dict)


@dataclass
class JobResult:
    """What a job gives back: figures or an error."""

    job: Job
    drive_name: str | None = None
    drive_params: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] | None = None
    config: dict[str, Any] | None = None
    estimate: Any = None
    error: str | None = None
    traceback: str | None = None
    #: The estimator refused the drive for lacking a channel it needs (e.g.
    #: accelerometers on Plaza): reported as "n/a", not counted as a failure.
    not_applicable: bool = False

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def failed(self) -> bool:
        return self.error is not None and not self.not_applicable


def _range_model(spec: Any) -> Any:
    if spec is None or not isinstance(spec, str):
        return spec
    from graphpos.ranging import load_range_model

    return load_range_model(spec)


def run_job(job: Job) -> JobResult:
    """Build the drive and the estimator, run it on the drive without truth, score against the truth; never raises."""
    from eval.metrics import evaluate_estimate, held_to_end
    from graphpos.registry import make_estimator
    from graphpos.settings import config_dict

    result = JobResult(job)
    try:
        drive = load_drive(job.source)
        result.drive_name = drive.name
        result.drive_params = dict(drive.params)
        est = make_estimator(job.estimator, settings=job.settings, layout=job.layout, range_model=_range_model(job.range_model),
                             initial_pose=job.initial_pose, profile=job.profile)
        result.config = config_dict(est.config)
        t0 = time.perf_counter()
        estimate = est.run(drive.without_truth())  # truth is for scoring only (issue 13)
        if estimate.wall_time_s != estimate.wall_time_s:  # NaN: the estimator did not time itself
            estimate = dataclasses.replace(estimate, wall_time_s=time.perf_counter() - t0)
        scored = held_to_end(estimate, drive.truth.t_s[-1]) if job.hold_last_output and drive.has("truth") else estimate
        result.metrics = evaluate_estimate(drive, scored)
        result.metrics["diagnostics"] = estimate.diagnostics
        if job.keep_estimate:
            result.estimate = estimate
    except MissingChannelError as exc:
        result.error = str(exc)
        result.not_applicable = True
    except GraphposError as exc:
        result.error = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # a bug in an estimator must not sink the sweep; it is reported
        result.error = f"{type(exc).__name__}: {exc}"
        result.traceback = traceback.format_exc()
    return result


@contextmanager
def executor(workers: int | None = None, scheduler: str | None = None, tasks: int | None = None) -> Iterator[Executor]:
    """A process pool (``workers`` processes, default: all cores) or a Dask cluster's executor.

    ``tasks``: how many tasks it will run, when known; the pool starts no more processes than that (each
    costs a second or so of imports: ``--workers 1000`` for one run took 100 s against 5)."""
    if scheduler:
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - dask is a dependency
            raise ConfigError("--scheduler needs the 'distributed' package") from None
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise ConfigError(f"cannot reach the Dask scheduler at {scheduler} ({exc})") from None
        try:
            yield client.get_executor()
        finally:
            client.close()
        return
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    processes = workers or os.cpu_count() or 1
    with ProcessPoolExecutor(max_workers=max(min(processes, tasks or processes), 1), initializer=_one_blas_thread) as pool:
        yield pool


def _one_blas_thread() -> None:
    """One BLAS thread per worker process: the pool already uses every core."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def execute(jobs: list[Job], workers: int | None = None, scheduler: str | None = None,
            progress: bool = True, desc: str = "runs", pool: Executor | None = None) -> list[JobResult]:
    """Run every job; results in the order of ``jobs``. ``pool``: an open :func:`executor` to run
    them on (a command that executes many small batches keeps one), else one made for these jobs."""
    if not jobs:
        return []
    results: list[JobResult | None] = [None] * len(jobs)
    with (nullcontext(pool) if pool is not None else executor(workers, scheduler, tasks=len(jobs))) as pool:
        futures = {pool.submit(run_job, job): i for i, job in enumerate(jobs)}
        bar = tqdm(total=len(jobs), desc=desc, unit="run", disable=not progress, leave=False)
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                results[i] = fut.result()
            except Exception as exc:  # the worker itself died (killed, out of memory, unpicklable)
                results[i] = JobResult(jobs[i], error=f"worker failed: {type(exc).__name__}: {exc}")
            bar.update(1)
        bar.close()
    return results  # type: ignore[return-value]


def provenance() -> dict[str, Any]:
    """Versions of the packages that made the figures, the host and the time."""
    import importlib.metadata as md
    import platform

    versions = {}
    for pkg in ("graphpos", "numpy", "scipy", "gtsam", "matplotlib", "dask", "distributed", "mcap"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = None
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "packages": versions,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def failures(results: list[JobResult]) -> list[JobResult]:
    """The failed results (not those where the estimator does not apply)."""
    return [r for r in results if r.failed]


def describe_source(source: Any) -> dict[str, Any]:
    """JSON description of a job's drive source."""
    if isinstance(source, Drive):
        return {"drive": source.name}
    return source.describe()
