"""Speed of the song2016 estimators on a 10-minute simulated drive.

Prints, per estimator, the wall time of ``run``, its CPU time (the process's
own, less sensitive to other work on a shared machine) and how many times
faster than real time each is (issue 4 asks for at least 200x: under 3 s).

    python benchmarks/bench_filters_song2016.py [--duration 600] [--scenario paper-straight] [--repeat 3] [-e NAME ...]

The drive has the papers' rates: 100 Hz IMU and wheel, 10 Hz compass, 1 Hz
RFID. The best of ``--repeat`` runs is reported (the machine is shared).
The estimators are timed on the drive without its truth
(:meth:`graphpos.drive.Drive.without_truth`; truth is for scoring only,
issue 13), as every scoring command runs them.
"""

from __future__ import annotations

import argparse
import time

from filters.song2016 import ESTIMATORS
from graphpos.sim import simulate

LAYOUTS = {"fukf": "optimized"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="drive length, s (default 600)")
    ap.add_argument("--scenario", default="paper-straight")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("-e", "--estimator", action="append", help="estimator name (default: all of song2016)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    drive = simulate(args.scenario, seed=args.seed, duration_s=args.duration).without_truth()
    counts = ", ".join(f"{k} {len(v)}" for k, v in drive.channels.items())
    print(f"drive {drive.name}: {drive.duration_s:.0f} s ({counts}); simulated in {time.perf_counter() - t0:.1f} s")
    print(f"{'estimator':<16} {'layout':<10} {'wall s':>8} {'x real':>8} {'cpu s':>8} {'x real':>8}")
    for name in args.estimator or list(ESTIMATORS):
        cls = ESTIMATORS[name]
        layout = LAYOUTS.get(name)
        walls, cpus = [], []
        for _ in range(args.repeat):
            c0 = time.process_time()
            walls.append(cls(layout=layout).run(drive).wall_time_s)
            cpus.append(time.process_time() - c0)
        wall, cpu = min(walls), min(cpus)
        dur = drive.duration_s
        print(f"{name:<16} {layout or 'dense':<10} {wall:8.3f} {dur / wall:8.0f} {cpu:8.3f} {dur / cpu:8.0f}")


if __name__ == "__main__":
    main()
