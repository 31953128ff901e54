"""Speed and memory of the GTSAM estimators (issue 6).

Prints, as ratios to real time:

- a ``--short`` (default 10-minute) simulated drive with 100 Hz IMU:
  ``graph-isam2`` (target >= 100x real time, p95 update < 5 ms),
  ``graph-batch`` (target < 5 s) and ``graph-fixed-lag``;
- a ``--long`` (default 60-minute) drive: ``graph-fixed-lag``'s cost
  against its short-drive cost (target <= 6.5x) and its resident memory
  through the run (target: flat). The short-drive cost is the mean of a run
  before and a run after the long one. The CPU time of each sixth of the
  long drive is printed too: a flat cost shows as equal sixths, and a drift
  of the machine's speed as a trend shared with the short runs. Then
  (issue 19) ``graph-isam2``'s CPU per sixth of the long drive (target:
  the last at most 1.5x the first) and ``graph-batch``'s peak resident
  memory through ``run`` (target under 1 GB).

    python benchmarks/graph.py [--scenario paper-straight] [--short 600] [--long 3600]
                               [--parameterisation auto|planar|inertial] [--skip-long]
    python benchmarks/graph.py --replay-only [--scenario paper-straight] [--short 600]
    python benchmarks/graph.py --late-figure late.png [--seed 0]
    python benchmarks/graph.py --accuracy [--seeds 12] [--first-seed 0]

``--accuracy`` prints the RMS position error of fusion-ekf, fukf,
graph-isam2 (causal) and graph-batch on seeded paper-straight and
paper-comprehensive drives with the optimized (16-tag) layout, and the
graph/best-filter ratios (issue 6 targets: batch <= 0.6, iSAM2 <= 1.0).

``--late-figure`` instead compares, on a ``paper-straight`` drive whose RFID
readings arrive 0.5-2 s late, graph-isam2 (late readings attached at their
own timestamp), graph-isam2 dropping them (``max_delay_s=0``) and the
fusion-ekf filter (applies each reading when it arrives): causal RMS
printed, error against time plotted.

Every estimator is handed the drive without its truth
(:meth:`graphpos.drive.Drive.without_truth`; truth is for scoring only,
issue 13); the errors are computed against the full drive afterwards.

Wall time suffers from other work on a shared machine; the CPU time of this
process (``time.process_time``) is printed beside it, and the long/short
cost ratio uses CPU time.

After the short-drive lines (alone with ``--replay-only``), each graph
estimator's CPU is compared with a GTSAM-only replay of the same work
(issue 19; target: ``graph-batch`` and ``graph-isam2`` at most 1.6x), by
:mod:`gtsam_replay` (in this directory):

- the estimator is run once under a recorder that copies the inputs of
  every GTSAM solving call it makes: iSAM2 and fixed-lag updates (the
  forced relinearisations and range rebuilds included), the
  ``calculateEstimate*`` / ``calculateBestEstimate`` reads, marginal
  covariances, Levenberg-Marquardt solves (``optimise``) and batch
  ``Marginals``;
- before that, twice: the estimator is run unrecorded (``run`` on the
  drive without its truth, as a user would; graph-batch's self-calibration
  included) and its CPU time taken; after it, twice, the recorded calls are
  redone in the same order on fresh GTSAM objects and their CPU time
  taken. Each replay must reproduce the recorded results to 1e-9 (the
  final LM values, every iSAM2 estimate read, every covariance), and each
  unrecorded run the recorded run's output, else the benchmark stops: a
  wrong replay cannot print a flattering ratio.

Each estimator is measured in a process of its own (warmed up on a 30 s
drive, then its runs, its recording and its replays), and timed before
its recording exists: what a process has run and holds changes its
speed. In one process (600 s drive), graph-isam2 took 7.8 s CPU before
recording, 9.1-9.4 s while the recording was held and 7.8 s again once it
was dropped (graph-batch 19.5, 20.2, 19.2 s); run after graph-batch's
figures in the same process it took 9.3-9.5 s. Its replay, which must
hold its recording, slowed by 3 % when a second recording was held too
(4.50 -> 4.64 s). Holding 300,000 pybind objects alone slowed graph-isam2
by 4 % (a numpy ballast or 200 MB of bytes: not at all), so GTSAM objects
kept alive are part of it. The same run with the recording held is
printed for comparison.

The ratio is estimator CPU / replay CPU, the i-th run against the i-th
replay: 1.0 would mean no cost outside GTSAM. The replay excludes
everything but the GTSAM calls: building factors and graphs, preintegration,
reading the drive, output rows, the profile fitting of self-calibration
(the pybind conversion of each call's arguments and results is in both).
Both ratios are printed; on a shared machine their spread shows the noise.
Below each, the recorded run's CPU is split into ``GraphBuilder.add`` and
``flush`` (per-measurement Python), ``GraphBuilder.graph`` (whole-graph
rebuilds for the batch solves), the GTSAM calls as timed inside the
estimator, and the rest; the recorder's own copying is shown apart. Its
"run less copies / its GTSAM" is a cross-check of the ratio from within a
single run (immune to the machine's speed changing between runs, but its
GTSAM calls run with caches the Python between them has disturbed).

"p95 update" is the 95th percentile of the wall time of one keyframe's
smoother update plus reading its estimate; "per keyframe" is the whole
online cost (preintegration, factor building, update, covariance) divided
by the number of keyframes.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np

from graphpos.graph import ESTIMATORS
from graphpos.graph.config import GraphConfig
from graphpos.sim import simulate


def rss_mb() -> float:
    """Resident set size of this process, MB (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * 4096 / 1e6


def timed_run(name: str, drive, config: GraphConfig, sample_rss: bool = False) -> dict:
    """Run ``name`` on ``drive`` (without its truth) through start/process/finish.

    ``sample_rss``: also sample the resident memory and the CPU time at the
    start and after each sixth of the measurements.
    """
    est = ESTIMATORS[name](config)
    drive = est.prepare(drive.without_truth())
    measurements = list(drive.measurements(est.channels_used(drive)))
    rss, cpu_marks = [], []
    checkpoints = set(np.linspace(0, len(measurements) - 1, 7).astype(int).tolist()) if sample_rss else set()
    t0 = time.perf_counter()
    c0 = time.process_time()
    est.start(drive)
    for i, m in enumerate(measurements):
        est.process(m)
        if i in checkpoints:
            rss.append(rss_mb())
            cpu_marks.append(time.process_time())
    result = est.finish()
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    d = result.diagnostics
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "realtime_x": drive.duration_s / wall,
        "realtime_cpu_x": drive.duration_s / cpu,
        "per_keyframe_ms": wall / max(d["keyframes"], 1) * 1e3,
        "update_mean_ms": d["update_ms_mean"],
        "update_p95_ms": d["update_ms_p95"],
        "parameterisation": d["parameterisation"],
        "rss_mb": rss,
        "cpu_per_sixth_s": np.diff(cpu_marks).tolist(),
    }


#: The graph estimators compared with their GTSAM-only replay (issue 19).
REPLAYED = ("graph-batch", "graph-isam2", "graph-fixed-lag")


def replay_figures(args: argparse.Namespace) -> None:
    """Print each graph estimator's CPU against a GTSAM-only replay of its calls, each in a process of its own."""
    print(f"CPU against a GTSAM-only replay of the same calls, {args.short:.0f} s drive, each estimator in a fresh process "
          f"(issue 19 target: graph-batch, graph-isam2 <= 1.6x):", flush=True)
    for name in REPLAYED:
        cmd = [sys.executable, __file__, "--replay-estimator", name, "--scenario", args.scenario, "--seed", str(args.seed),
               "--short", str(args.short), "--parameterisation", args.parameterisation]
        subprocess.run(cmd, check=True)


def replay_one(name: str, drive, config: GraphConfig, repeats: int = 2) -> None:
    """One estimator's CPU against a GTSAM-only replay of its calls (see the module docstring)."""
    from gtsam_replay import Recorder

    blind = drive.without_truth()
    runs = []  # timed before the recording exists: holding it slows the estimator (module docstring)
    for _ in range(repeats):
        c0 = time.process_time()
        est = ESTIMATORS[name](config).run(blind)
        runs.append((time.process_time() - c0, est))
    with Recorder() as rec:
        recorded = ESTIMATORS[name](config).run(blind)
    for _, est in runs:
        for col in ("t_s", "east_m", "north_m", "yaw_rad", "cov_en_m2"):
            a, b = getattr(est, col, None), getattr(recorded, col, None)
            if (a is None) != (b is None) or (a is not None and not np.array_equal(a, b, equal_nan=True)):
                raise AssertionError(f"{name}: the recorded run's {col} differs from the unrecorded run's")
    c0 = time.process_time()
    ESTIMATORS[name](config).run(blind)
    held_s = time.process_time() - c0
    figures = []
    for cpu_s, _ in runs:
        replay = rec.replay()
        replay.check()
        figures.append((cpu_s, replay.cpu_s))
        del replay
    counts = rec.counts()
    print(f"  {name:16s} " + "; ".join(f"CPU {c:6.2f} s, replay {r:6.2f} s: {c / r:.2f}x" for c, r in figures))
    print(f"  {'':16s} calls: " + ", ".join(f"{n} {k}" for k, n in counts.items()) + "; replay reproduced every result to 1e-9")
    print(f"  {'':16s} the same run with the recording held: CPU {held_s:.2f} s ({held_s / np.mean([c for c, _ in runs]):.2f}x the runs above)")
    print(f"  {'':16s} recorded run: {rec.split.describe()}", flush=True)


def late_figure(path: str, seed: int) -> None:
    """Causal error with 0.5-2 s RFID latency: graph at the timestamp vs filter at arrival."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from filters import ESTIMATORS as FILTERS

    drive = simulate("paper-straight", seed=seed, rfid_latency_s=(0.5, 2.0)).with_layout("optimized")
    on_time = simulate("paper-straight", seed=seed).with_layout("optimized")
    late, prompt = drive.without_truth(), on_time.without_truth()  # truth only scores (issue 13)
    runs = {
        "graph-isam2, late readings at their timestamp": (ESTIMATORS["graph-isam2"]().run(late), drive),
        "graph-isam2, late readings dropped": (ESTIMATORS["graph-isam2"](GraphConfig(max_delay_s=0.0)).run(late), drive),
        "graph-isam2, no latency (reference)": (ESTIMATORS["graph-isam2"]().run(prompt), on_time),
        "fusion-ekf, late readings at arrival": (FILTERS["fusion-ekf"]().run(late), drive),
        "fusion-ekf, no latency (reference)": (FILTERS["fusion-ekf"]().run(prompt), on_time),
    }
    fig, ax = plt.subplots(figsize=(9, 4))
    for label, (est, scored_on) in runs.items():
        tr = scored_on.truth
        keep = est.t_s <= tr.t_s[-1]
        t = est.t_s[keep]
        err = np.hypot(est.east_m[keep] - np.interp(t, tr.t_s, tr.east_m), est.north_m[keep] - np.interp(t, tr.t_s, tr.north_m))
        print(f"  {label:48s} causal RMS {np.sqrt(np.mean(err**2)):.3f} m, max {err.max():.2f} m")
        ax.plot(t, err, label=label, lw=1.0, ls="--" if "reference" in label else "-")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position error (m)")
    ax.set_title(f"paper-straight seed {seed}, optimized layout, RFID arriving 0.5-2 s late")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"  figure: {path}")


def accuracy(seeds: int, first_seed: int = 0) -> None:
    """Graph vs the best song2016 filter on the papers' drives (seeds ``first_seed`` ... ``first_seed + seeds - 1``)."""
    from filters import ESTIMATORS as FILTERS

    names = ("fusion-ekf", "fukf", "graph-isam2", "graph-batch")
    for scenario in ("paper-straight", "paper-comprehensive"):
        rms = {n: [] for n in names}
        for seed in range(first_seed, first_seed + seeds):
            drive = simulate(scenario, seed=seed)
            tr = drive.truth
            blind = drive.without_truth()
            for n in names:
                est = (FILTERS[n] if n in FILTERS else ESTIMATORS[n])(layout="optimized").run(blind)
                err = np.hypot(est.east_m - np.interp(est.t_s, tr.t_s, tr.east_m), est.north_m - np.interp(est.t_s, tr.t_s, tr.north_m))
                rms[n].append(float(np.sqrt(np.mean(err**2))))
        mean = {n: float(np.mean(v)) for n, v in rms.items()}
        best = min(mean["fusion-ekf"], mean["fukf"])
        print(f"{scenario}, optimized layout, {seeds} seeds from {first_seed}: mean RMS " + ", ".join(f"{n} {mean[n]:.3f} m" for n in names))
        print(f"  graph-batch / best filter {mean['graph-batch'] / best:.2f} (target <= 0.6), graph-isam2 / best filter {mean['graph-isam2'] / best:.2f} (target <= 1.0)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper-straight")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--short", type=float, default=600.0, help="short drive, s (default 600)")
    ap.add_argument("--long", type=float, default=3600.0, help="long drive, s (default 3600)")
    ap.add_argument("--parameterisation", default="auto", choices=("auto", "planar", "inertial"))
    ap.add_argument("--skip-long", action="store_true")
    ap.add_argument("--replay-only", action="store_true", help="only the CPU against a GTSAM-only replay of each graph estimator's calls")
    ap.add_argument("--replay-estimator", choices=REPLAYED, help=argparse.SUPPRESS)  # --replay-only's child process
    ap.add_argument("--late-figure", metavar="PNG", help="plot the late-reading comparison instead")
    ap.add_argument("--accuracy", action="store_true", help="compare with the song2016 filters instead")
    ap.add_argument("--seeds", type=int, default=12, help="--accuracy: drives per scenario (default 12; one drive's RMS varies 3x between seeds)")
    ap.add_argument("--first-seed", type=int, default=0, help="--accuracy: first seed (fresh seeds confirm a gain found on others)")
    args = ap.parse_args()
    if args.accuracy:
        accuracy(args.seeds, args.first_seed)
        return
    if args.late_figure:
        late_figure(args.late_figure, args.seed)
        return
    config = GraphConfig(parameterisation=args.parameterisation)

    short = simulate(args.scenario, seed=args.seed, duration_s=args.short)
    if not args.replay_estimator:
        print(f"{args.scenario} seed {args.seed}: {short.duration_s:.0f} s drive, IMU {len(short.imu)} samples", flush=True)
    if args.replay_estimator:
        warm = simulate(args.scenario, seed=args.seed, duration_s=30.0).without_truth()
        ESTIMATORS[args.replay_estimator](config).run(warm)  # imports and caches, outside the figures
        replay_one(args.replay_estimator, short, config)
        return
    if args.replay_only:
        replay_figures(args)
        return
    results = {}
    for name in ("graph-isam2", "graph-batch", "graph-fixed-lag"):
        r = timed_run(name, short, config)
        results[name] = r
        print(
            f"  {name:16s} [{r['parameterisation']}] {r['wall_s']:7.2f} s = {r['realtime_x']:6.1f}x real time "
            f"(CPU {r['cpu_s']:.2f} s = {r['realtime_cpu_x']:.1f}x), "
            f"{r['per_keyframe_ms']:.2f} ms/keyframe, update mean {r['update_mean_ms']:.2f} ms, p95 {r['update_p95_ms']:.2f} ms"
        )
    replay_figures(args)
    if args.skip_long:
        return
    long = simulate(args.scenario, seed=args.seed, duration_s=args.long)
    r = timed_run("graph-fixed-lag", long, config, sample_rss=True)
    # the short run again after the long one: on a shared machine the CPU's
    # speed drifts over minutes, and the ratio should not measure that drift
    short_after = timed_run("graph-fixed-lag", short, config)
    short_cpu_s = 0.5 * (results["graph-fixed-lag"]["cpu_s"] + short_after["cpu_s"])
    print(f"  graph-fixed-lag on the {short.duration_s:.0f} s drive again: CPU {short_after['cpu_s']:.2f} s (before: {results['graph-fixed-lag']['cpu_s']:.2f} s)")
    ratio = r["cpu_s"] / short_cpu_s
    print(
        f"{long.duration_s:.0f} s drive: graph-fixed-lag {r['wall_s']:.1f} s = {r['realtime_x']:.1f}x real time "
        f"(CPU {r['cpu_s']:.1f} s), CPU "
        f"{ratio:.2f}x its {short.duration_s:.0f} s cost (mean of before and after; length ratio {long.duration_s / short.duration_s:.1f}), "
        f"update p95 {r['update_p95_ms']:.2f} ms"
    )
    print("  CPU per sixth of the drive (s): " + ", ".join(f"{x:.2f}" for x in r["cpu_per_sixth_s"]) + " (flat cost: equal sixths, up to the machine's own drift)")
    rss = r["rss_mb"]
    print("  RSS through the run (MB): " + ", ".join(f"{x:.0f}" for x in rss) + f"; growth after the first sixth {rss[-1] - rss[1]:+.0f} MB")
    long_drive_figures(long, config, args.scenario, args.seed, args.long)


def long_drive_figures(drive, config: GraphConfig, scenario: str, seed: int, duration_s: float) -> None:
    """Issue 19 item 4 on the long drive: graph-isam2's CPU per sixth (target: last <= 1.5x first) and
    graph-batch's peak resident memory through ``run`` (target < 1 GB), in a fresh process (as ``graphpos run``
    would: this one keeps what the runs before left), sampled every 0.2 s."""
    import multiprocessing

    r = timed_run("graph-isam2", drive, config, sample_rss=True)
    sixths = r["cpu_per_sixth_s"]
    print(f"  graph-isam2: CPU {r['cpu_s']:.1f} s = {r['realtime_cpu_x']:.1f}x real time; per sixth (s): "
          + ", ".join(f"{x:.2f}" for x in sixths) + f"; last / first {sixths[-1] / sixths[0]:.2f} (target <= 1.5)")
    context = multiprocessing.get_context("spawn")
    with context.Pool(1) as pool:
        cpu_s, peak_mb = pool.apply(batch_memory, (scenario, seed, duration_s, config))
    print(f"  graph-batch: CPU {cpu_s:.1f} s, peak resident memory {peak_mb:.0f} MB "
          "(a fresh process's, the drive simulated in it included; target < 1000 MB)")


def batch_memory(scenario: str, seed: int, duration_s: float, config: GraphConfig) -> tuple[float, float]:
    """CPU time and peak resident memory (MB) of graph-batch's ``run`` on a simulated drive, in this process."""
    import threading

    drive = simulate(scenario, seed=seed, duration_s=duration_s).without_truth()
    peak, done = [rss_mb()], threading.Event()

    def sample() -> None:
        while not done.wait(0.2):
            peak[0] = max(peak[0], rss_mb())

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    c0 = time.process_time()
    ESTIMATORS["graph-batch"](config).run(drive)
    done.set()
    sampler.join()
    return time.process_time() - c0, max(peak[0], rss_mb())


if __name__ == "__main__":
    main()
