"""MCAP write/read time of a 60-minute drive (issue 2: each under 30 s), and
the time of the exports of ``graphpos run`` (issue 19).

Simulates a drive with ``graphpos.sim.simulate`` (scenario ``long-tunnel``
by default) or, with ``--synthetic`` or while the simulator cannot make
one, builds a drive with the same channel rates (imu, wheel and truth at
100 Hz, compass 10 Hz, rfid 1-5 readings per second) from seeded noise.
Prints message count, write and read seconds (wall and CPU: the machine is
shared), file size, and checks the read drive equals the written one; then
the CPU seconds of the truth's CSV text
(:func:`graphpos.io.exports.csv_text`), of ``estimates.mcap`` (the drive
and one estimate: :func:`graphpos.io.write_drive`) and of all the exports
of that estimate (:func:`graphpos.io.exports.write_exports`), and the
process's peak memory. The estimate stands in for an estimator's output:
the truth at 10 Hz with noise, velocity, yaw and covariance. Each time is
the best of ``--repeat`` runs.

    python benchmarks/mcap_io.py [--duration 3600] [--scenario long-tunnel] [--synthetic] [--repeat 3]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from graphpos.drive import Channel, Drive, TagMap, Window
from graphpos.estimate import Estimate
from graphpos.io import read_drive, write_drive
from graphpos.io.exports import csv_text, truth_estimate, write_exports


def synthetic_drive(duration_s: float, seed: int = 0) -> Drive:
    """A drive at the simulator's channel rates: a 20 m/s straight road with
    tags every 6 m on both walls, noisy sensors."""
    rng = np.random.default_rng(seed)
    t100 = np.arange(0.0, duration_s, 0.01)
    n = t100.size
    speed = 20.0 + 0.5 * np.sin(t100 / 30.0)
    east = np.cumsum(speed) * 0.01
    tag_east = np.arange(0.0, east[-1] + 6.0, 6.0)
    tag_ids = np.arange(2 * tag_east.size)
    tags = TagMap(
        tag_ids,
        np.repeat(tag_east, 2),
        np.tile([3.0, -3.0], tag_east.size),
        np.tile([1, -1], tag_east.size),
        np.repeat(np.arange(tag_east.size) // 5, 2),
        layouts={"optimized": tag_ids[::4]},
    )
    t_rfid = np.repeat(np.arange(0.0, duration_s, 1.0), rng.integers(1, 6, int(np.ceil(duration_s))))[: int(3 * duration_s)]
    heard = np.clip(np.searchsorted(tag_east, np.interp(t_rfid, t100, east)) * 2 + rng.integers(-2, 2, t_rfid.size), 0, tag_ids.size - 1)
    t10 = t100[::10]
    channels = {
        "imu": Channel("imu", {
            "t_s": t100,
            "accel_x_mps2": rng.normal(0, 0.1, n),
            "accel_y_mps2": rng.normal(0, 0.1, n),
            "yaw_rate_radps": rng.normal(0, 0.0035, n),
        }),
        "wheel": Channel("wheel", {"t_s": t100, "speed_mps": speed * 1.01 + rng.normal(0, 0.1, n)}),
        "compass": Channel("compass", {"t_s": t10, "yaw_rad": rng.normal(0, 0.05, t10.size)}),
        "rfid": Channel("rfid", {
            "t_s": t_rfid,
            "tag_id": tag_ids[heard],
            "rss": rng.uniform(60, 200, t_rfid.size).round(),
            "true_range_m": rng.uniform(3, 9, t_rfid.size),
        }),
        "truth": Channel("truth", {
            "t_s": t100,
            "east_m": east,
            "north_m": np.zeros(n),
            "v_east_mps": speed,
            "v_north_mps": np.zeros(n),
            "yaw_rad": np.zeros(n),
            "yaw_rate_radps": np.zeros(n),
            "accel_x_mps2": np.gradient(speed, t100),
            "accel_y_mps2": np.zeros(n),
        }),
    }
    return Drive("synthetic", channels, tags=tags, windows=(Window("in_tunnel", 0.0, duration_s),), params={"seed": seed})


def stand_in_estimate(drive: Drive, seed: int = 0) -> Estimate:
    """An estimate of the drive at 10 Hz, as a filter gives one: the truth
    with noise, its velocity and yaw, a covariance."""
    rng = np.random.default_rng(seed)
    truth = drive.truth
    keep = np.arange(0, len(truth), 10)
    n = keep.size
    noise = lambda sigma: rng.normal(0.0, sigma, n)  # noqa: E731
    var = np.abs(noise(0.5)) + 0.01
    cov = np.stack([var, 0.1 * var, 0.1 * var, var], axis=1).reshape(n, 2, 2)
    return Estimate("stand-in", truth.t_s[keep], truth.east_m[keep] + noise(0.3), truth.north_m[keep] + noise(0.3),
                    truth.v_east_mps[keep] + noise(0.05), truth.v_north_mps[keep] + noise(0.05), truth.yaw_rad[keep] + noise(0.01),
                    cov_en_m2=cov, rate_hz=10.0)


def best_of(repeat: int, run) -> tuple[float, float]:
    """The least wall and CPU seconds of ``repeat`` calls of ``run(k)`` (k = 0, 1, ...)."""
    wall, cpu = [], []
    for k in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        run(k)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def simulated_drive(scenario: str, duration_s: float) -> Drive | None:
    try:
        from graphpos.sim import simulate
    except ImportError:
        return None
    return simulate(scenario, seed=0, duration_s=duration_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3600.0, help="drive length, s")
    parser.add_argument("--scenario", default="long-tunnel")
    parser.add_argument("--synthetic", action="store_true", help="do not use the simulator")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each timing (the best is printed)")
    args = parser.parse_args()

    t0 = time.perf_counter()
    drive = None if args.synthetic else simulated_drive(args.scenario, args.duration)
    source = f"simulated '{args.scenario}'" if drive is not None else "synthetic"
    drive = drive or synthetic_drive(args.duration)
    print(f"drive: {source}, {drive.duration_s:.0f} s, built in {time.perf_counter() - t0:.1f} s")
    print("rows: " + ", ".join(f"{k} {len(ch)}" for k, ch in drive.channels.items()))
    estimate = stand_in_estimate(drive)

    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        path = folder / "drive.mcap"
        write_s, write_cpu_s = best_of(args.repeat, lambda k: write_drive(path, drive))
        read_s, read_cpu_s = best_of(args.repeat, lambda k: read_drive(path))
        back = read_drive(path)
        with open(path, "rb") as f:
            stats = make_reader(f).get_summary().statistics
        size_mb = path.stat().st_size / 1e6
        _, estimates_cpu_s = best_of(args.repeat, lambda k: write_drive(folder / "estimates.mcap", drive, [estimate]))
        _, exports_cpu_s = best_of(args.repeat, lambda k: write_exports(folder / f"exports{k}", drive, [estimate]))
    same = all(back.channels[k] == ch for k, ch in drive.channels.items()) and back.tags == drive.tags
    truth = truth_estimate(drive)
    _, csv_cpu_s = best_of(args.repeat, lambda k: csv_text(truth))
    print(f"messages: {stats.message_count} ({stats.chunk_count} chunks)")
    print(f"write: {write_s:.2f} s (CPU {write_cpu_s:.2f} s)   read: {read_s:.2f} s (CPU {read_cpu_s:.2f} s)   "
          f"file: {size_mb:.1f} MB   lossless: {same}")
    print(f"truth CSV: CPU {csv_cpu_s:.3f} s ({len(truth)} rows)")
    print(f"estimates.mcap (the drive and one estimate of {len(estimate)} rows): CPU {estimates_cpu_s:.2f} s")
    print(f"write_exports of that estimate (CSV, TUM, KML, GeoJSON, estimates.mcap, ROS 2 bag): CPU {exports_cpu_s:.2f} s")
    print(f"best of {args.repeat}; peak memory of the process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB")


if __name__ == "__main__":
    main()
